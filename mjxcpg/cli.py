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
    from mjxcpg.sim import make_simulation

    if args.checkpoint is not None:
        from mjxcpg import checkpoint

        sim, feedback, fb_params = checkpoint.load_walker(
            Path(args.checkpoint), learner=args.learner, engine=args.engine, slope_deg=args.slope)
    else:
        sim = make_simulation(args.engine, args.slope)
        if args.controller == "in-place":
            sim.params = dataclasses.replace(sim.params, amp_x=0.0)
        gain = {"hand": sim.params.hand_gain, "stepping": 0.0, "in-place": 0.0}[args.controller]
        feedback = lambda obs, k: k * obs.gyro[0]  # noqa: E731  the hand-designed a_5 with gain k
        fb_params = jnp.array([gain])
    steps = round(args.seconds / sim.control_dt)
    run = walk.make_walk(sim.engine, sim.layout, sim.params, steps, feedback)
    trace = run(sim.engine.init(sim.qpos0, 1), walk.initial_cpg(1), fb_params)
    summary = walk.summarise(trace, sim.control_dt)[0].as_dict()
    summary.update(engine=sim.engine.name, slope_deg=args.slope,
                   controller="learned" if args.checkpoint else args.controller)
    return summary


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
