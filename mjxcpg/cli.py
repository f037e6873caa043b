"""The ``mjxcpg`` command line: walk, learn, sweep, eval, render, bench.

MuJoCo is imported only inside the commands (and the parser), so that ``render`` can choose
its headless OpenGL back end (``MUJOCO_GL``) before MuJoCo reads it, at import."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from pathlib import Path

import mjxcpg


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
    from mjxcpg.physics.model import MAX_SLOPE_DEG

    value = float(text)
    if not -MAX_SLOPE_DEG <= value <= MAX_SLOPE_DEG:
        raise argparse.ArgumentTypeError(f"must be within +/-{MAX_SLOPE_DEG:g} degrees, got {text}")
    return value


def cmd_walk(args: argparse.Namespace) -> dict:
    import jax.numpy as jnp

    from mjxcpg.control import walk
    from mjxcpg.control.controller import roll_rate_feedback
    from mjxcpg.control.sim import make_simulation

    if args.checkpoint is not None:
        import jax

        from mjxcpg.learning.learner import policy_mean_feedback
        from mjxcpg.training.runs import check_learners, load_run

        spec, sim, task, state = load_run(Path(args.checkpoint), args.engine, args.slope)
        check_learners(spec, [args.learner])
        feedback = policy_mean_feedback(task)
        fb_params = jax.tree.map(lambda w: w[args.learner:args.learner + 1], state.learners.weights)
    else:
        sim = make_simulation(args.engine, args.slope)
        if args.controller == "in-place":
            sim.params = dataclasses.replace(sim.params, amp_x=0.0)
        gain = {"hand": sim.params.hand_gain, "stepping": 0.0, "in-place": 0.0}[args.controller]
        feedback = roll_rate_feedback
        fb_params = jnp.array([gain])
    trace = walk.walk_from_standing(sim, feedback, fb_params, args.seconds)
    summary = walk.summarise(trace, sim.control_dt)[0].as_dict()
    summary.update(engine=sim.engine.name, slope_deg=args.slope,
                   controller="learned" if args.checkpoint else args.controller)
    return summary


def _learn_or_sweep(spec, args, out: Path) -> dict:
    from mjxcpg import api

    return api.sweep(spec, out, args.engine, resume=args.resume, force=args.force, progress=not args.quiet,
                     tensorboard=args.tensorboard)


def cmd_learn(args: argparse.Namespace) -> dict:
    from mjxcpg.training.config import validate
    from mjxcpg.learning.learner import TrialParams
    from mjxcpg.training.train import RunSpec

    if args.from_run is not None:
        return _learn_online(args)
    if args.robot != "nominal" or args.reward is not None:
        raise UserError("--robot and --reward need --from: learning from scratch runs on the nominal robot")
    args.k_s = 10.0 if args.k_s is None else args.k_s
    args.seed = 0 if args.seed is None else args.seed
    spec = validate(RunSpec(k_s=(args.k_s,), seeds=(args.seed,),
                            trial=TrialParams(max_trials=1000 if args.trials is None else args.trials)))
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


def _learn_online(args: argparse.Namespace) -> dict:
    """``learn --from DIR --learner K``: continue that learner on ``--robot`` (mjxcpg.training.online)."""
    from mjxcpg.training import online

    if args.k_s is not None or args.seed is not None:
        raise UserError("--k-s and --seed come from the checkpoint with --from")
    if args.resume:
        raise UserError("--resume does not apply to --from; rerun with --force")
    source = Path(args.from_run)
    out = Path(args.out or f"runs/online_{source.name}_learner{args.learner}_{args.robot}")
    trials = 400 if args.trials is None else args.trials
    return online.learn_online(source, args.learner, out, trials=trials, robot=args.robot,
                               reward=args.reward, engine=args.engine, force=args.force,
                               progress=not args.quiet, tensorboard=args.tensorboard) | {"out": str(out)}


def cmd_render(args: argparse.Namespace) -> dict:
    from mjxcpg.evaluation import render

    out = Path(args.out or Path(args.run) / "render")
    try:
        return render.render_gait(Path(args.run), args.learner, out, seconds=args.seconds,
                                  engine=args.engine, robot=args.robot, gif=args.gif)
    except render.RenderError as error:
        raise UserError(str(error)) from None


def _choose_headless_gl(argv: list[str]) -> None:
    """Before MuJoCo is imported: give ``render`` a headless OpenGL unless MUJOCO_GL is set."""
    if argv[:1] != ["render"] or "MUJOCO_GL" in os.environ or "mujoco" in sys.modules:
        return
    from mjxcpg.evaluation.render import headless_gl_backend

    backend = headless_gl_backend()
    if backend is not None:
        os.environ["MUJOCO_GL"] = backend


def cmd_sweep(args: argparse.Namespace) -> dict:
    from mjxcpg.training.config import load_spec

    spec = load_spec(args.config)
    out = Path(args.out or f"runs/{Path(args.config).stem}")
    summary = _learn_or_sweep(spec, args, out)
    print((out / "table1.md").read_text())
    ok = sum(r["succeeded"] for r in summary["learners"])
    return {"out": str(out), "learners": len(summary["learners"]), "succeeded": ok,
            "wall_s": summary["wall_s"], "engine": summary["engine"]}


def cmd_controls(args: argparse.Namespace) -> dict:
    from mjxcpg.training import controls

    run_dir = Path(args.run)
    if not (run_dir / "summary.json").is_file():
        raise UserError(f"{run_dir} holds no finished run (no summary.json); run the sweep first")
    walls = controls.run_controls(run_dir, args.only or tuple(controls.CONTROLS),
                                  trials=args.trials or controls.DEFAULT_TRIALS,
                                  engine=args.engine, resume=args.resume, force=args.force,
                                  progress=not args.quiet, tensorboard=args.tensorboard)
    print((run_dir / "table1.md").read_text())
    return {"out": str(run_dir / "controls"), "wall_s": walls}


def cmd_transfer(args: argparse.Namespace) -> dict:
    from mjxcpg.evaluation import transfer

    if not (Path(args.run) / "summary.json").is_file():
        raise UserError(f"{args.run} holds no finished run (no summary.json); run the sweep first")
    result = transfer.walk_on_engines(Path(args.run), args.seconds)
    for r in result["learners"]:
        print(f"learner {r['learner']:3d}  k_s {r['k_s']:4g}  C {r['mean_vx_c']:.4f}  MJX {r['mean_vx_mjx']:.4f}"
              f"  MJX/C {r['mjx_over_c']:.3f}" + ("  fell on C" if r["fell_c"] else "")
              + ("  fell on MJX" if r["fell_mjx"] else ""))
    return {k: v for k, v in result.items() if k != "learners"} | {"out": str(Path(args.run) / "transfer.json")}


def _nonnegative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def cmd_eval(args: argparse.Namespace) -> dict:
    """``eval --run DIR``: velocity (Fig 7), return map (Fig 8), slopes and pushes of the run's
    final policies, all learners in one batch; JSON and PNG under OUT/eval, OUT/report.md."""
    from mjxcpg import api

    overrides = {name: getattr(args, name) for name in (
        "seed", "fixed_point_steps", "perturbations", "slope_seconds", "max_slope_deg", "push_rounds")
        if getattr(args, name) is not None}
    progress = None if args.quiet else (lambda text: print(f"eval: {text}", file=sys.stderr, flush=True))
    return api.evaluate_policies(args.run, args.learner or None, args.engine, args.robot,
                                 api.EvalParams(**overrides),
                                 parts=[p for p in api.EVALUATIONS if p not in (args.skip or [])],
                                 transfer_repeats=args.transfer_repeats, out=args.out, progress=progress)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def cmd_bench(args: argparse.Namespace) -> dict | None:
    """``bench``: robot-steps/s of every engine side by side (``mjxcpg.bench``).  The table goes
    to stdout, or to stderr with --json so that stdout is the JSON report alone."""
    from mjxcpg import bench

    options = bench.Options(control_steps=args.control_steps, seconds=args.seconds,
                            budget_seconds=args.budget_seconds)
    log = None if args.quiet else (lambda line: print(f"bench: {line}", file=sys.stderr, flush=True))
    result = bench.benchmark(args.engines, args.models, args.batches, args.workloads, options, log)
    table = sys.stderr if args.json else sys.stdout
    print(bench.format_table(result["results"], result["skipped"], args.engines), file=table)
    print(bench.format_overheads(result["overheads"]), file=table)
    return result if args.json else None


def _print_result(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result))
    else:
        width = max(map(len, result))
        for key, value in result.items():
            print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


def build_parser() -> argparse.ArgumentParser:
    from mjxcpg.training.config import config_names
    from mjxcpg.physics.engines import ENGINES
    from mjxcpg.control.sim import ROBOTS

    parser = _Parser(prog="mjxcpg", description=__doc__)
    parser.add_argument("--version", action="version", version=f"%(prog)s {mjxcpg.__version__}")
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
        p.add_argument("--quiet", action="store_true", help="no progress line")
        p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                       help="write no TensorBoard event files (OUT/tensorboard)")
        p.add_argument("--json", action="store_true", help="print one JSON object as the last line")

    learn = sub.add_parser("learn", help="one learner learns the propulsive feedback a_5")
    learn.add_argument("--k-s", type=float, default=None, help="velocity reward gain k_S of eq 27 (default 10)")
    learn.add_argument("--seed", type=int, default=None, help="default 0")
    learn.add_argument("--trials", type=int, default=None,
                       help="trial budget (default 1000; 400 with --from)")
    learn.add_argument("--from", dest="from_run", metavar="DIR",
                       help="continue learner --learner of this run (online additional learning)")
    learn.add_argument("--learner", type=int, default=0, help="learner index within --from's run")
    learn.add_argument("--robot", choices=ROBOTS, default="nominal",
                       help="robot to continue on with --from (hardware: docs/hardware.md)")
    learn.add_argument("--reward", choices=("estimate", "truth"), default=None,
                       help="with --from: reward from the robot's sensors (default on hardware) "
                            "or the simulator's state (default on nominal)")
    run_options(learn)
    learn.set_defaults(handler=cmd_learn)

    sweep = sub.add_parser("sweep", help="many learners in lockstep (the paper's Table 1)")
    sweep.add_argument("--config", default="paper",
                       help=f"a config that ships with mjxcpg ({', '.join(config_names())}) or a .toml/.json path")
    run_options(sweep)
    sweep.set_defaults(handler=cmd_sweep)

    ctl = sub.add_parser("controls", help="the run's protocol without learning, without a_5, and with "
                         "the hand-designed feedback, beside its Table 1")
    ctl.add_argument("--run", required=True, help="a finished sweep's run directory")
    ctl.add_argument("--trials", type=_positive_int, default=None,
                     help="trial budget of each control learner (default 400, at most the run's)")
    ctl.add_argument("--only", nargs="+", choices=("learning_off", "learning_off_min_sigma", "zero_feedback",
                                                   "hand_feedback"), help="run only these controls")
    ctl.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
    ctl.add_argument("--resume", action="store_true", help="continue controls already started")
    ctl.add_argument("--force", action="store_true", help="replace controls already run")
    ctl.add_argument("--quiet", action="store_true", help="no progress line")
    ctl.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                     help="write no TensorBoard event files")
    ctl.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    ctl.set_defaults(handler=cmd_controls)

    tr = sub.add_parser("transfer", help="walk a run's final policies on MuJoCo C and on MJX")
    tr.add_argument("--run", required=True, help="a finished run directory")
    tr.add_argument("--seconds", type=_positive_seconds, default=20.0)
    tr.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    tr.set_defaults(handler=cmd_transfer)

    rend = sub.add_parser("render", help="filmstrip PNG and MP4 video of a learned gait (headless OpenGL)")
    rend.add_argument("--run", required=True, help="run directory")
    rend.add_argument("--learner", type=int, default=0, help="learner index within the run")
    rend.add_argument("--seconds", type=_positive_seconds, default=10.0, help="length of the walk")
    rend.add_argument("--robot", choices=ROBOTS, default="nominal")
    rend.add_argument("--engine", choices=ENGINES, default=None, help="default: the run's")
    rend.add_argument("--out", help="output directory (default: RUN/render)")
    rend.add_argument("--gif", action="store_true", help="also write the video's frames as an animated GIF")
    rend.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    rend.set_defaults(handler=cmd_render)

    evaluation = sub.add_parser("eval", help="evaluate a run's learned policies as the paper did "
                                "(velocity, return map, slopes, pushes)")
    evaluation.add_argument("--run", required=True, help="run directory (learn or sweep)")
    evaluation.add_argument("--learner", type=int, nargs="+", help="learner indices (default: all)")
    evaluation.add_argument("--engine", choices=ENGINES, default=None, help="default: the run's")
    evaluation.add_argument("--robot", choices=ROBOTS, default="nominal", help="robot the policies walk on")
    evaluation.add_argument("--seed", type=_nonnegative_int, default=None, help="evaluation seed (default 0)")
    evaluation.add_argument("--fixed-point-steps", type=_nonnegative_int, default=None,
                            help="unperturbed gait cycles for velocity and fixed point (default 100)")
    evaluation.add_argument("--perturbations", type=_nonnegative_int, default=None,
                            help="return-map perturbations (default 50)")
    evaluation.add_argument("--slope-seconds", type=_positive_seconds, default=None,
                            help="walk on each slope this long (default 20)")
    evaluation.add_argument("--max-slope-deg", type=_nonnegative_int, default=None,
                            help="steepest inclination tried each way (default 15)")
    evaluation.add_argument("--push-rounds", type=_nonnegative_int, default=None,
                            help="bisection rounds per push direction (default 7)")
    evaluation.add_argument("--skip", nargs="+", choices=("return_map", "slopes", "pushes", "transfer"),
                            help="evaluations to leave out (transfer: --robot hardware only)")
    evaluation.add_argument("--transfer-repeats", type=_positive_int, default=20,
                            help="with --robot hardware: walks per policy, each with other sensor noise")
    evaluation.add_argument("--out", help="write eval/ and report.md here (default: the run directory; "
                                           "with --robot hardware, its hardware/ subdirectory)")
    evaluation.add_argument("--quiet", action="store_true", help="no progress lines")
    evaluation.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    evaluation.set_defaults(handler=cmd_eval)

    from mjxcpg import bench

    bench_parser = sub.add_parser("bench", help="robot-steps/s of every engine, batch size, model and "
                                  "workload, side by side (bench/README.md)")
    bench_parser.add_argument("--engines", nargs="+", choices=ENGINES, default=list(ENGINES))
    bench_parser.add_argument("--models", nargs="+", choices=bench.MODELS, default=list(bench.MODELS),
                              help="qrio: our robot; humanoid: MJX's benchmark model (physics only)")
    bench_parser.add_argument("--batches", nargs="+", type=_positive_int, default=list(bench.BATCHES),
                              help="robots stepped together")
    bench_parser.add_argument("--workloads", nargs="+", choices=bench.WORKLOADS, default=list(bench.WORKLOADS),
                              help="physics: physics alone; full: physics + controller + learner")
    bench_parser.add_argument("--seconds", type=_positive_seconds, default=bench.Options.seconds,
                              help="timed seconds per measurement, after a warm-up call")
    bench_parser.add_argument("--budget-seconds", type=_positive_seconds, default=bench.Options.budget_seconds,
                              help="stepping time a measurement may take (compilation apart); "
                                   "cases projected past it are skipped")
    bench_parser.add_argument("--control-steps", type=_positive_int, default=bench.Options.control_steps,
                              help="control periods per timed call")
    bench_parser.add_argument("--quiet", action="store_true", help="no progress lines")
    bench_parser.add_argument("--json", action="store_true",
                              help="print the report as one JSON object, the last line of stdout")
    bench_parser.set_defaults(handler=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    _choose_headless_gl(argv)
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


def entry(argv: list[str] | None = None) -> int:
    """The ``mjxcpg`` program: ``main`` in a process whose XLA:CPU is set up for this library."""
    from mjxcpg.jaxutil import xla

    xla.one_cpu_thread()
    return main(argv)


if __name__ == "__main__":
    sys.exit(entry())
