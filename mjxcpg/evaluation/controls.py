"""Controls beside Table 1: the run's protocol with one ingredient of learning taken away.

Each control is the run's own config (same k_s, seeds, trials, reward and success test)
with the learner changed, and runs through the same batch machinery:

* ``learning_off``: no weight updates; sigma as initialised;
* ``learning_off_min_sigma``: no weight updates; sigma fixed at the smallest value the
  learner may reach (w^sigma at its lower bound);
* ``zero_feedback``: a_5 = 0 after the hand-over;
* ``hand_feedback``: the hand-designed a_5 = K d theta_roll/dt throughout.

A learner that only learned to stop exploring would pass the success test as
``learning_off_min_sigma`` does; the learned policies must beat it on the reward.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from mjxcpg.report import learning as report
from mjxcpg.training import runs
from mjxcpg.training.files import write_text_atomic
from mjxcpg.training.train import RunSpec

CONTROLS = {
    "learning_off": "learning off, sigma as initialised",
    "learning_off_min_sigma": "learning off, sigma at its smallest",
    "zero_feedback": "a_5 = 0",
    "hand_feedback": "hand-designed feedback",
}
DEFAULT_TRIALS = 400


def control_spec(spec: RunSpec, name: str, trials: int = DEFAULT_TRIALS) -> RunSpec:
    """The run's spec with control ``name`` (one of ``CONTROLS``) and a budget of ``trials``."""
    trial = dataclasses.replace(spec.trial, max_trials=min(trials, spec.trial.max_trials),
                                trials_after_success=0)
    learner = dataclasses.replace(spec.learner, rate_scale=0.0)
    if name == "learning_off_min_sigma":
        if spec.learner.w_sigma_bounds is None:
            raise runs.RunError("the run's sigma has no lower bound (learner.w_sigma_bounds)")
        learner = dataclasses.replace(learner, init_w_sigma=spec.learner.w_sigma_bounds[0])
    elif name == "zero_feedback":
        trial = dataclasses.replace(trial, actor="zero")
    elif name == "hand_feedback":
        trial = dataclasses.replace(trial, actor="hand")
    elif name != "learning_off":
        raise ValueError(f"unknown control {name!r}; choose from {', '.join(CONTROLS)}")
    return dataclasses.replace(spec, learner=learner, trial=trial)


def run_controls(run_dir: Path, names=tuple(CONTROLS), trials: int = DEFAULT_TRIALS,
                 engine: str | None = None, resume: bool = False, force: bool = False,
                 progress: bool = True, tensorboard: bool = True) -> dict:
    """Run the controls of the run in ``run_dir`` into ``run_dir/controls/NAME`` and rewrite
    the run's table1.md with them beside its learners.  Returns each control's wall time."""
    spec, _ = runs.read_config(run_dir)
    specs = {name: control_spec(spec, name, trials) for name in names}  # every refusal before any run
    walls_path = run_dir / "controls" / "wall_s.json"
    # The run's lock covers its controls, which write into its table1.md.
    with runs.locked(run_dir):
        for name in specs:  # refused before any control runs, not after the first ones
            runs.check_replaceable(run_dir / "controls" / name, resume or force,
                                   "pass --resume to continue the controls or --force to run them again")
        walls = json.loads(walls_path.read_text()) if walls_path.is_file() else {}
        for name, cspec in specs.items():
            out = run_dir / "controls" / name
            if resume and runs.is_finished(out):
                continue  # its results stay as they are
            sim, task, state, wall_s = runs.execute(out, cspec, engine, resume=resume, force=force,
                                                    progress=progress, tensorboard=tensorboard)
            report.write_report(out, cspec, sim, task, state, plots_too=False)
            walls[name] = wall_s
            write_text_atomic(walls_path, json.dumps(walls, indent=1))
        report.write_table1(run_dir)
    return walls
