"""The benchmark command works and refuses bad input; no timing is checked here."""

import json

from mjxcpg.cli import main

RECORD_KEYS = {"engine", "model", "batch", "workload", "robot_steps_per_s", "compile_s"}
TINY = ["--engines", "mujoco", "--workloads", "physics", "--seconds", "0.01", "--control-steps", "2", "--quiet"]


def test_json_report_is_the_last_line(capsys):
    assert main(["bench", *TINY, "--batches", "2", "1", "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert {"cpu", "cores", "jax_backend", "versions"} <= set(report["machine"])
    records = report["results"]
    assert {(r["model"], r["batch"]) for r in records} == {("qrio", 1), ("qrio", 2), ("humanoid", 1), ("humanoid", 2)}
    for record in records:
        assert RECORD_KEYS <= set(record)
        assert record["engine"] == "mujoco" and record["workload"] == "physics"
        assert record["robot_steps_per_s"] > 0
        # our robot's physics is also replayed in a compiled scan; the humanoid's is raw C only
        assert (record["compile_s"] > 0) if record["model"] == "qrio" else (record["compile_s"] is None)
    assert "steps/s" in captured.err  # the table goes to the terminal, off stdout


def test_a_case_over_budget_is_skipped_not_faked(capsys):
    assert main(["bench", *TINY, "--models", "qrio", "--batches", "1", "--budget-seconds", "1e-9", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["results"] == []
    assert [(s["engine"], s["batch"]) for s in report["skipped"]] == [("mujoco", 1)]
    assert "budget" in report["skipped"][0]["reason"]
