"""mjxcpg installs like a library: the wheel carries its configs and robot, and a fresh virtual
environment outside the repository runs a sweep from another directory."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import mjxcpg

REPO = Path(__file__).resolve().parent.parent


def _run(argv, **kwargs) -> subprocess.CompletedProcess:
    done = subprocess.run(argv, capture_output=True, text=True, **kwargs)
    assert done.returncode == 0, f"{argv}: {done.stderr[-3000:]}"
    return done


@pytest.mark.slow
def test_the_wheel_installs_and_sweeps_from_another_directory(tmp_path):
    # built from a copy: a build writes build/ and mjxcpg.egg-info/ beside the sources
    source = tmp_path / "source"
    shutil.copytree(REPO, source, ignore=shutil.ignore_patterns(
        ".git", ".venv", "runs", "build", "*.egg-info", "__pycache__", ".pytest_cache"))
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "--wheel-dir", str(tmp_path / "dist"),
          str(source)], timeout=600)
    [wheel] = (tmp_path / "dist").glob("mjxcpg-*.whl")
    assert wheel.name.startswith(f"mjxcpg-{mjxcpg.__version__}-")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"mjxcpg/configs/quick.toml", "mjxcpg/configs/paper.toml", "mjxcpg/robots/qrio/qrio.xml"} <= names

    # nothing of this checkout or of the test's environment may be seen from the fresh one
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], env=env, timeout=300)
    _run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", str(wheel)], env=env, timeout=1800)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    installed = _run([str(venv / "bin" / "python"), "-c", "import mjxcpg; print(mjxcpg.__file__)"],
                     cwd=elsewhere, env=env, timeout=300).stdout.strip()
    assert Path(installed).is_relative_to(venv), installed
    version = _run([str(venv / "bin" / "python"), "-m", "mjxcpg", "--version"], cwd=elsewhere, env=env,
                   timeout=300).stdout
    assert version.strip() == f"mjxcpg {mjxcpg.__version__}"

    swept = _run([str(venv / "bin" / "mjxcpg"), "sweep", "--config", "quick", "--out", "runs/quick", "--quiet"],
                 cwd=elsewhere, env=env, timeout=1800)
    print(f"fresh environment {venv}, in {elsewhere}:\n$ mjxcpg sweep --config quick --out runs/quick --quiet\n"
          + swept.stdout)
    assert "| all | 3 |" in swept.stdout                       # Table 1: the quick config's 3 learners
    assert (elsewhere / "runs" / "quick" / "table1.md").is_file()
    assert list((elsewhere / "runs" / "quick" / "tensorboard").glob("learner_*/events.out.tfevents.*"))
