"""The progress line's estimate of trials left, replayed from a finished run's events.

At 10%, 50% and 90% of the run's wall time (as ``bench/eta_accuracy.py``), each learner's
trials and falls up to then are read back from its TensorBoard events, and
``progress.sampled_total_trials`` draws every learner's total (``progress.ETA_DRAWS`` draws):
from its finished peers or Lindy's law, bounded by the streak its fall rates over its history
predict (``progress.history_fall_rate``, the progress line's), or its fall rate over the last
50 trials, or over the last 20, or not bounded.  Printed: the
trials left of the learner that in fact had the most (the run's critical path), and the mean
over the draws of the most trials any learner has left, which is what the batch waits for.

    NPROC=1 .venv/bin/python bench/eta_replay.py runs/printed
"""

import sys
from pathlib import Path

import numpy as np

from mjxcpg.training import progress, runs
from mjxcpg.training.events import read_events

FRACTIONS = (0.1, 0.5, 0.9)


def replay(run: Path) -> None:
    spec, _ = runs.read_config(run)
    trial, k_s = spec.trial, np.array(spec.k_s)
    # learner_KK_ks..._seed...: in the order of the run's learners, by KK
    folders = sorted((p for p in (run / "tensorboard").iterdir() if p.name.startswith("learner_")),
                     key=lambda p: int(p.name.split("_")[1]))
    events = [[(wall, values["trial/fell"] > 0.5) for wall, _, values in read_events(f)] for f in folders]
    total = np.array([len(e) for e in events])
    walls = sorted({wall for e in events for wall, _ in e})
    print(f"{run}: trials left, as they were and as drawn (mean over {progress.ETA_DRAWS} draws)\n"
          "| at | learners left | most left | drawn: most left, bounded by history | last 50 | last 20 | not bounded "
          "| learner with most left | its trials then | its trials left | drawn, history | drawn, last 50 |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")
    for fraction in FRACTIONS:
        then = walls[0] + fraction * (walls[-1] - walls[0])
        trials = np.array([sum(wall <= then for wall, _ in e) for e in events])
        falls = np.zeros((len(events), trial.max_trials), bool)
        streak, to_success = np.zeros(len(events), int), np.full(len(events), -1)
        for i, e in enumerate(events):
            for n, (_, fell) in enumerate(e[:trials[i]]):
                falls[i, n] = fell
                streak[i] = 0 if fell else streak[i] + 1
                if streak[i] >= trial.success_streak and to_success[i] < 0:
                    to_success[i] = n + 1
        done = trials >= total
        critical = int(np.argmax(total - trials))
        left = {}
        bounds = {"history": progress.history_fall_rate(falls, trials, trial.success_streak),
                  50: progress.recent_fall_rate(falls, trials, 50), 20: progress.recent_fall_rate(falls, trials, 20),
                  None: None}
        for bound, rate in bounds.items():
            left[bound] = progress.sampled_total_trials(trial, k_s, trials, streak, to_success, done,
                                                        progress.ETA_DRAWS, np.random.default_rng(0), rate) - trials
        print(f"| {fraction:.0%} | {int(np.sum(~done))} | {np.max(total - trials)} | "
              + " | ".join(f"{left[w].max(axis=1).mean():.0f}" for w in bounds)
              + f" | {critical} | {trials[critical]} | {total[critical] - trials[critical]} "
              f"| {left['history'][:, critical].mean():.0f} | {left[50][:, critical].mean():.0f} |")


if __name__ == "__main__":
    for run in sys.argv[1:]:
        replay(Path(run))
