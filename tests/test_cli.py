"""The command line: JSON output and one-line errors."""

import argparse
import json

import pytest

import mjxcpg
from mjxcpg import api
from mjxcpg.cli import build_parser, main


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
    ["learn", "--k-s", "nan", "--seed", "0", "--trials", "5"],
    ["learn", "--seed", "-1"],
    ["learn", "--trials", "0"],
    ["learn", "--trials", "1e3"],
    ["learn", "--trials", "1" + "0" * 400],
    ["eval", "--run", "x", "--max-slope-deg", "31"],
    ["walk", "--platform", "atlas"],
    ["sweep", "--platform", "atlas"],
    ["learn", "--platform", "atlas"],
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


def _numeric_flags() -> list[tuple[str, str]]:
    """(command, flag) of every option whose text the parser turns into something."""
    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return [(name, action.option_strings[-1]) for name, sub in commands.choices.items()
            for action in sub._actions if action.type is not None]


@pytest.mark.parametrize("command, flag", _numeric_flags())
@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_every_numeric_flag_rejects_non_finite_values(command, flag, value, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--run", "x", flag, value] if command in ("eval", "render", "controls", "transfer")
             else [command, flag, value])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mjxcpg {command}: error: argument {flag}") and "\n" not in err


@pytest.mark.parametrize("text, key", [
    ("k_s = [nan]\nseeds = [0]\n", "k_s[0]"),
    ("k_s = [1.0]\nseeds = [-3]\n", "seeds[0]"),
    ("k_s = [1.0]\nseeds = [0]\n[learner]\na_max = inf\n", "learner.a_max"),
    ("k_s = [1.0]\nseeds = [0]\n[learner]\nkappa_c = 0.0\n", "learner.kappa_c"),
    ("k_s = [1.0]\nseeds = [0]\n[controller.cpg]\ntau = -0.1\n", "controller.cpg.tau"),
    ("k_s = [1.0]\nseeds = [0]\n[trial]\nhand_seconds = [-1.0, 2.0]\n", "trial.hand_seconds[0]"),
    ("k_s = [1.0]\nseeds = [0]\nchunk_seconds = nan\n", "chunk_seconds"),
])
def test_bad_config_value_is_one_line_and_exit_2(tmp_path, text, key, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    assert main(["sweep", "--config", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mjxcpg: error: {key}: must be") and "\n" not in err
    assert not (tmp_path / "run").exists()



def test_non_boolean_switch_in_a_config_is_one_line_and_exit_2(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text('k_s = [1.0]\nseeds = [0]\n[learner]\nunit_slope = "false"\n')
    assert main(["sweep", "--config", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "mjxcpg: error: learner.unit_slope: expected true or false, got 'false'"


@pytest.mark.parametrize("text, kind", [("[1, 2]", "list"), ('"paper"', "str")])
def test_json_config_that_is_not_a_table_is_one_line_and_exit_2(tmp_path, text, kind, capsys):
    """A run's returns.json (a list) given as a config, for example."""
    path = tmp_path / "returns.json"
    path.write_text(text)
    assert main(["sweep", "--config", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mjxcpg: error: {path}: a config is a table of keys, not a {kind}"
    assert not (tmp_path / "run").exists()


def test_learn_resumed_when_finished_keeps_its_record(tmp_path, capsys):
    """``learn --resume`` on a finished learner: exit 0 and no file changed."""
    out = tmp_path / "learn"
    argv = ["learn", "--k-s", "10", "--seed", "0", "--trials", "2", "--out", str(out), "--quiet",
            "--no-tensorboard"]
    assert main(argv) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"}
    assert (out / "learn.json").is_file() and (out / "policy_map.png").is_file()
    assert main(argv + ["--resume"]) == 0
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != ".lock"} == before


def test_the_package_names_are_the_apis():
    """``import mjxcpg`` lists the API's names itself, so that importing it loads no JAX:
    they must be the API's."""
    assert set(mjxcpg.__all__) - {"__version__"} == set(api.__all__)


@pytest.mark.parametrize("argv, message", [
    (["walk", "--checkpoint", "/nonexistent/run", "--controller", "stepping"], "give one of them"),
    (["eval", "--run", "/nonexistent/run", "--transfer-repeats", "3"], "applies to --robot hardware, harsh or harsher only"),
])
def test_a_flag_that_does_not_apply_is_refused_not_ignored(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_learn_on_the_child_records_its_platform_and_walk_refuses_another(tmp_path, capsys):
    """``learn --platform child`` learns with the child's gait constants (its leg is twice
    QRIO's: Z_0 = 2 x 0.215 m, h' = 2 x 0.272 m); walking its checkpoint as QRIO is an error."""
    out = tmp_path / "child"
    assert main(["learn", "--platform", "child", "--k-s", "10", "--seed", "0", "--trials", "1", "--out", str(out),
                 "--quiet", "--no-tensorboard"]) == 0
    spec = json.loads((out / "config.json").read_text())["spec"]
    assert spec["platform"] == "child"
    assert spec["controller"]["z0"] == pytest.approx(0.43) and spec["trial"]["h_ref"] == pytest.approx(0.544)
    capsys.readouterr()
    assert main(["walk", "--checkpoint", str(out), "--platform", "qrio", "--seconds", "1"]) == 2
    assert capsys.readouterr().err.strip() == f"mjxcpg: error: {out} was learned on child, not qrio"
