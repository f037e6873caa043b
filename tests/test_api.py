"""The README's Python API example runs as it stands, and its numbers are the run's."""

import json
import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"


def readme_example() -> str:
    section = README.read_text().split("## Python API", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readme_example_runs(tmp_path):
    done = subprocess.run([sys.executable, "-c", readme_example()], cwd=tmp_path, capture_output=True,
                          text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    succeeded_line, trials_line, report_line = done.stdout.strip().splitlines()[-3:]
    run = tmp_path / "runs" / "api_quick"
    learners = json.loads((run / "summary.json").read_text())["learners"]
    assert [learner["seed"] for learner in learners] == [3, 4, 5]  # the spec as the example changed it
    assert succeeded_line == f"{sum(l['succeeded'] for l in learners)} of 3 succeeded"
    returns = json.loads((run / "returns.json").read_text())
    assert trials_line == f"trials per learner: {[len(r['returns']) for r in returns]}"
    report = Path(report_line.removeprefix("report: "))
    assert report == Path("runs/api_quick/report.md") and (tmp_path / report).is_file()
    slopes = json.loads((run / "eval" / "evaluation.json").read_text())["learners"]
    assert len(slopes) == 1 and "slopes" in slopes[0] and "return_map" not in slopes[0]
    assert (run / "tensorboard" / "learner_00_ks10_seed3").is_dir()
