"""The ``mjxcpg`` command line: walk, learn, sweep, bench."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

from mjxcpg.engines import ENGINES


class UserError(Exception):
    """Bad input: reported as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``--help`` still shows the usage)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive_seconds(text: str) -> float:
    value = float(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _slope(text: str) -> float:
    from mjxcpg.robot import MAX_SLOPE_DEG

    value = float(text)
    if not -MAX_SLOPE_DEG <= value <= MAX_SLOPE_DEG:
        raise argparse.ArgumentTypeError(f"must be within +/-{MAX_SLOPE_DEG:g} degrees, got {text}")
    return value


def cmd_walk(args: argparse.Namespace) -> dict:
    import jax.numpy as jnp

    from mjxcpg import walk
    from mjxcpg.controller import roll_rate_feedback
    from mjxcpg.sim import make_simulation

    if args.checkpoint is not None:
        import jax

        from mjxcpg.learner import policy_mean_feedback
        from mjxcpg.runs import load_run

        spec, sim, task, state = load_run(Path(args.checkpoint), args.engine, args.slope)
        if not 0 <= args.learner < spec.batch:
            raise UserError(f"--learner {args.learner} is out of range: the run has {spec.batch} learner(s)")
        feedback = policy_mean_feedback(task)
        fb_params = jax.tree.map(lambda w: w[args.learner:args.learner + 1], state.learners.weights)
    else:
        sim = make_simulation(args.engine, args.slope)
        if args.controller == "in-place":
            sim.params = dataclasses.replace(sim.params, amp_x=0.0)
        gain = {"hand": sim.params.hand_gain, "stepping": 0.0, "in-place": 0.0}[args.controller]
        feedback = roll_rate_feedback
        fb_params = jnp.array([gain])
    steps = round(args.seconds / sim.control_dt)
    run = walk.make_walk(sim.engine, sim.layout, sim.params, steps, feedback)
    trace = run(sim.engine.init(sim.qpos0, 1), walk.initial_cpg(1), fb_params)
    summary = walk.summarise(trace, sim.control_dt)[0].as_dict()
    summary.update(engine=sim.engine.name, slope_deg=args.slope,
                   controller="learned" if args.checkpoint else args.controller)
    return summary


def _learn_or_sweep(spec, args, out: Path) -> dict:
    from mjxcpg import report, runs

    sim, task, state, wall_s = runs.execute(out, spec, args.engine, resume=args.resume,
                                            force=args.force, progress=not args.quiet)
    summary = report.write_report(out, spec, sim, task, state)
    summary["wall_s"] = wall_s
    return summary


def cmd_learn(args: argparse.Namespace) -> dict:
    from mjxcpg.config import validate
    from mjxcpg.learner import TrialParams
    from mjxcpg.train import RunSpec

    spec = validate(RunSpec(k_s=(args.k_s,), seeds=(args.seed,), trial=TrialParams(max_trials=args.trials)))
    out = Path(args.out or f"runs/learn_ks{args.k_s:g}_seed{args.seed}")
    summary = _learn_or_sweep(spec, args, out)
    learner = summary["learners"][0]
    returns = json.loads((out / "returns.json").read_text())[0]
    result = {"succeeded": learner["succeeded"], "trials_to_success": learner["trials_to_success"],
              "trials": learner["trials"], "mean_vx": learner["mean_vx"],
              "final_policy_fell": learner["final_policy_fell"],
              "policy_input_gradient": learner["policy_input_gradient"],
              "wall_s": summary["wall_s"], "engine": summary["engine"], "out": str(out),
              "returns": returns["returns"], "falls": returns["falls"]}
    (out / "learn.json").write_text(json.dumps(result, indent=1))
    (out / "learning_curve_ks{:g}.png".format(args.k_s)).rename(out / "learning_curve.png")
    (out / "policy_map_00.png").rename(out / "policy_map.png")
    return {k: v for k, v in result.items() if k not in ("returns", "falls")}


def cmd_sweep(args: argparse.Namespace) -> dict:
    from mjxcpg.config import load_spec

    spec = load_spec(args.config)
    out = Path(args.out or f"runs/{Path(args.config).stem}")
    summary = _learn_or_sweep(spec, args, out)
    print((out / "table1.md").read_text())
    ok = sum(r["succeeded"] for r in summary["learners"])
    return {"out": str(out), "learners": len(summary["learners"]), "succeeded": ok,
            "wall_s": summary["wall_s"], "engine": summary["engine"]}


def _print_result(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result))
    else:
        width = max(map(len, result))
        for key, value in result.items():
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mjxcpg", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    walk = sub.add_parser("walk", help="walk with a controller and report the gait")
    walk.add_argument("--controller", choices=("hand", "stepping", "in-place"), default="hand",
                      help="hand: hand-designed a_5; stepping: a_5 = 0; in-place: a_5 = 0 and A_x = 0")
    walk.add_argument("--checkpoint", help="walk with the learned policy saved in this run directory")
    walk.add_argument("--learner", type=int, default=0, help="learner index within a sweep checkpoint")
    walk.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
    walk.add_argument("--seconds", type=_positive_seconds, default=20.0)
    walk.add_argument("--slope", type=_slope, default=0.0, help="floor slope in degrees (uphill > 0)")
    walk.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    walk.set_defaults(handler=cmd_walk)

    def run_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
        p.add_argument("--out", help="run directory (default: runs/...)")
        p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
        p.add_argument("--force", action="store_true", help="replace an existing --out")
        p.add_argument("--quiet", action="store_true", help="no progress bar")
        p.add_argument("--json", action="store_true", help="print one JSON object as the last line")

    learn = sub.add_parser("learn", help="one learner learns the propulsive feedback a_5")
    learn.add_argument("--k-s", type=float, default=10.0, help="velocity reward gain k_S of eq 27")
    learn.add_argument("--seed", type=int, default=0)
    learn.add_argument("--trials", type=int, default=1000, help="trial budget")
    run_options(learn)
    learn.set_defaults(handler=cmd_learn)

    sweep = sub.add_parser("sweep", help="many learners in lockstep (the paper's Table 1)")
    sweep.add_argument("--config", default="paper", help="a name in configs/ or a .toml/.json path")
    run_options(sweep)
    sweep.set_defaults(handler=cmd_sweep)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.handler(args)
    except (UserError, ValueError, FileNotFoundError) as error:
        print(f"mjxcpg: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mjxcpg: interrupted", file=sys.stderr)
        return 130
    if result is not None:
        _print_result(result, getattr(args, "json", False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
