"""``mjxcpg reproduce`` (``make run``): every stage into one report, a second call that runs
nothing, and an interrupted stage that ends with the same files as an uninterrupted run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mjxcpg import api
from mjxcpg.evaluation import controls, online
from mjxcpg.report import document
from mjxcpg.training.checkpoints import RunError

# Every stage, at a size the default suite affords: a few trials, short evaluations.
BUDGET = api.ReproductionBudget(
    control_trials=4, transfer_repeats=2, online_trials=3,
    eval_params=api.EvalParams(fixed_point_steps=6, perturbations=3, slope_seconds=2.0, max_slope_deg=1,
                               push_rounds=1))
RESULTS = ("summary.json", "returns.json", "stats.json", "table1.md", "report.md", "eval/evaluation.json",
           "hardware/eval/evaluation.json", "harsh/eval/evaluation.json",
           "harsher/eval/evaluation.json", "controls/learning_off/returns.json",
           "controls/learning_off_min_sigma/returns.json", "controls/zero_feedback/returns.json")


def results(out: Path) -> dict[str, str]:
    """The pipeline's result files, with the run directory's own name taken out of them."""
    return {name: (out / name).read_text().replace(str(out), "RUN") for name in RESULTS}


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reproduce") / "run"
    api.reproduce("quick", out, budget=BUDGET, progress=False)
    return out


def test_the_report_has_every_section(reproduced):
    report = (reproduced / "report.md").read_text()
    headings = [line for line in report.splitlines() if line.startswith("#")]
    for section in ("## Table 1: learning", "## Learning curves (Fig 4)", "## Policy maps (Fig 5)",
                    "## Velocity against k_s (Fig 7)", "## Return-map stability (Fig 8)", "## Slopes", "## Pushes",
                    "## Transfer to the hardware robot", "## Transfer to the `harsh` hardware robot",
                    "## Transfer to the `harsher` hardware robot", "## Online learning on the `harsher` hardware robot"):
        assert section in headings, section
    # every section says how to make it alone
    assert report.count("Alone: `mjxcpg ") >= 4
    assert "(c) a_5 = 0" in report  # the controls beside the learners


def test_a_second_call_runs_nothing_and_keeps_the_results(reproduced, monkeypatch):
    before = results(reproduced)

    def refuse(*args, **kwargs):
        raise AssertionError("a finished stage ran again")

    for module, name in ((api, "sweep"), (api, "evaluate_policies"), (controls, "run_controls"),
                         (online, "learn_online")):
        monkeypatch.setattr(module, name, refuse)
    api.reproduce("quick", reproduced, budget=BUDGET, progress=False)
    assert results(reproduced) == before


def test_an_interrupted_stage_ends_as_an_uninterrupted_run(reproduced, tmp_path, monkeypatch):
    """Interrupted once the hardware stage has written its output but before it is recorded as
    finished (the latest a kill can come), then called again: the stage runs again over its
    own output, and every file is as the uninterrupted run's."""
    out = tmp_path / "run"
    evaluate = api.evaluate_policies

    def evaluate_then_die(*args, **kwargs):
        evaluate(*args, **kwargs)
        if kwargs.get("robot") == "hardware":
            raise KeyboardInterrupt

    monkeypatch.setattr(api, "evaluate_policies", evaluate_then_die)
    with pytest.raises(KeyboardInterrupt):
        api.reproduce("quick", out, budget=BUDGET, progress=False)
    assert json.loads((out / document.PIPELINE_RECORD).read_text())["stages"]["hardware"] == "started"
    monkeypatch.setattr(api, "evaluate_policies", evaluate)
    api.reproduce("quick", out, budget=BUDGET, progress=False)
    assert results(out) == {name: text.replace(str(reproduced), "RUN") for name, text in results(reproduced).items()}


def test_the_online_sigma_as_text_is_the_same_setting(reproduced, monkeypatch):
    """--online-exploration's text "0.20" names the number 0.2, the default, so the finished
    reproduction is the same settings: nothing runs again, nothing is refused."""
    assert BUDGET.online_exploration == 0.2
    monkeypatch.setattr(online, "learn_online", lambda *a, **k: pytest.fail("online learning ran again"))
    before = results(reproduced)
    api.reproduce("quick", reproduced, budget=api.ReproductionBudget(**{**vars(BUDGET), "online_exploration": "0.20"}),
                  progress=False)
    assert results(reproduced) == before


def test_other_settings_in_the_same_directory_are_refused(reproduced):
    other = api.ReproductionBudget(**{**vars(BUDGET), "control_trials": 5})
    with pytest.raises(RunError, match="reproduction of other settings"):
        api.reproduce("quick", reproduced, budget=other, progress=False)


def test_an_evaluation_it_did_not_start_is_not_replaced(reproduced, tmp_path):
    """A sweep finished by hand and an ``eval`` run by hand in it: reproduce adopts the sweep
    and refuses to write over the evaluation."""
    out = tmp_path / "run"
    out.mkdir()
    for name in ("config.json", "summary.json", "returns.json", "table1.md", "stats.json"):
        (out / name).write_bytes((reproduced / name).read_bytes())
    (out / "checkpoints").symlink_to(reproduced / "checkpoints")
    (out / "eval").mkdir()
    (out / "report.md").write_text("the user's own evaluation\n")
    (out / "controls").mkdir()
    for name in BUDGET.controls:
        (out / "controls" / name).symlink_to(reproduced / "controls" / name)
    with pytest.raises(RunError, match="holds an earlier evaluation"):
        api.reproduce("quick", out, budget=BUDGET, progress=False)
    assert (out / "report.md").read_text() == "the user's own evaluation\n"


def test_the_online_section_lists_each_learner_beside_its_control(tmp_path):
    """Hand-written online.json files, as ``online.learn_online`` writes them, and their row."""
    row = {"learner": 3, "k_s": 4.0, "seed": 103, "succeeded": True, "trials_to_success": 57, "trials": 57,
           "falls_in_first_20": 6, "final_policy_walks_20s": True, "final_policy_mean_vx": 0.0612}
    for name, learner, succeeded in (("online", row, 1), ("online_control", row | {"succeeded": False,
                                                                                   "trials": 200}, 0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "online.json").write_text(json.dumps({
            "robot": "harsh", "trials": 200, "succeeded": succeeded, "learners": [learner]}))
    lines = document.online_section(tmp_path, {"online": "mjxcpg learn --from RUN ..."})
    assert "## Online learning on the `harsh` hardware robot" in lines
    assert "| 3 | 4 | 57 | 6 | yes | 0.061 | not in 200 |" in lines
    assert any(line.startswith("Met the criterion within 200 trials: **1 of 1** learning, 0 of 1 with learning off")
               for line in lines)
