"""The package's layers (pyproject.toml, [tool.importlinter]): every import points down, and
no two modules of a layer import each other in a circle, imports inside functions included."""

import shutil
import subprocess
import sys
from pathlib import Path

import mjxcpg

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = Path(mjxcpg.__file__).parent


def lint_imports(source_root: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the package found under ``source_root``, with this repository's contracts."""
    command = [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
               "sys.exit(lint_imports_command())", "--config", str(ROOT / "pyproject.toml"), "--no-cache"]
    return subprocess.run(command, cwd=source_root, capture_output=True, text=True,
                          env={"PYTHONPATH": str(source_root), "PATH": ""}, timeout=120)


def test_layers_are_kept():
    result = lint_imports(PACKAGE.parent)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 kept, 0 broken" in result.stdout


def _lint_with_added(tmp_path: Path, module: str, text: str):
    """lint-imports on a copy of the package whose ``module`` (a path in it) ends with ``text``."""
    copy = tmp_path / "mjxcpg"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    with (copy / module).open("a") as f:
        f.write(text)
    return lint_imports(tmp_path)


def test_an_upward_import_inside_a_function_is_caught(tmp_path):
    result = _lint_with_added(tmp_path, "physics/engines.py",
                              "\n\ndef _upward():\n    from mjxcpg.training import train\n    return train\n")
    assert result.returncode != 0
    assert "mjxcpg.physics.engines -> mjxcpg.training.train" in result.stdout


def test_a_cycle_within_a_layer_is_caught(tmp_path):
    result = _lint_with_added(tmp_path, "control/cpg.py", "\n\nfrom mjxcpg.control import controller  # noqa: E402\n")
    assert result.returncode != 0
    assert "acyclic" in result.stdout.lower() or "cycle" in result.stdout.lower()
    assert "BROKEN" in result.stdout
