"""The command line: JSON output and one-line errors."""

import json

import pytest

from mjxcpg.cli import main


@pytest.mark.parametrize("argv", [
    ["walk", "--seconds", "-1"],
    ["walk", "--engine", "bullet"],
    ["walk", "--slope", "90"],
    ["walk", "--seconds", "nan"],
    ["bench", "--engines", "bullet"],
    ["bench", "--batches", "0"],
    ["bench", "--batches", "two"],
    ["bench", "--models", "ant"],
    ["bench", "--workloads", "render"],
    ["bench", "--budget-seconds", "-5"],
])
def test_bad_input_is_one_line_and_nonzero(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mjxcpg") and "\n" not in err


def test_walk_json_is_the_last_line(capsys):
    assert main(["walk", "--engine", "mujoco", "--seconds", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("fell", "seconds", "mean_vx", "mean_pelvis_height", "gait_period", "engine"):
        assert key in result
    assert result["engine"] == "mujoco" and result["seconds"] == pytest.approx(3.0)


def test_the_program_gives_xla_one_cpu_thread_unless_nproc_is_set(monkeypatch):
    import os

    from mjxcpg.jaxutil import xla

    monkeypatch.delenv("NPROC", raising=False)
    xla.one_cpu_thread()
    assert os.environ["NPROC"] == "1"
    monkeypatch.setenv("NPROC", "8")
    xla.one_cpu_thread()
    assert os.environ["NPROC"] == "8"
