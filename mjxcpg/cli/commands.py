"""The commands of ``mjxcpg``: each takes the parsed arguments and returns what is printed
(a dict, or None).  MuJoCo and JAX are imported inside the commands, so that ``render`` can
choose its OpenGL back end before MuJoCo reads it."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path


class UserError(Exception):
    """Bad input: reported as one line, exit status 2."""


def hardware_robots_text() -> str:
    """The hardware robots' names as help and errors list them: "hardware, harsh or harsher"."""
    from mjxcpg.physics.hardware import MISMATCHES
    *others, last = MISMATCHES
    return f"{', '.join(others)} or {last}"


def cmd_walk(args: argparse.Namespace) -> dict:
    import jax.numpy as jnp

    from mjxcpg.control import walk
    from mjxcpg.control.controller import roll_rate_feedback
    from mjxcpg.control.sim import make_simulation
    from mjxcpg.robots import DEFAULT_PLATFORM

    if args.checkpoint is not None:
        import jax

        from mjxcpg.learning.learner import actor_feedback
        from mjxcpg.training.runs import check_learners, load_run

        if args.controller is not None:
            raise UserError("--controller walks a hand-designed controller, --checkpoint a learned one: "
                            "give one of them")
        spec, sim, task, state = load_run(Path(args.checkpoint), args.engine, args.slope)
        if args.platform not in (None, spec.platform):
            raise UserError(f"{args.checkpoint} was learned on {spec.platform}, not {args.platform}")
        check_learners(spec, [args.learner])
        feedback = actor_feedback(task)
        fb_params = jax.tree.map(lambda w: w[args.learner:args.learner + 1], state.learners.weights)
        # a control's run walks its own feedback, named as --controller names it
        controller = {"policy": "learned", "zero": "stepping", "hand": "hand"}[task.trial.actor]
    else:
        sim = make_simulation(args.engine, args.slope, platform=args.platform or DEFAULT_PLATFORM)
        controller = args.controller or "hand"
        if controller == "in-place":
            sim = sim.rebuild(params=dataclasses.replace(sim.params, amp_x=0.0))
        gain = {"hand": sim.params.hand_gain, "stepping": 0.0, "in-place": 0.0}[controller]
        feedback = roll_rate_feedback
        fb_params = jnp.array([gain])
    trace = walk.walk_from_standing(sim, feedback, fb_params, args.seconds)
    summary = walk.summarise(trace, sim.control_dt, sim.layout.weight)[0].as_dict()
    summary.update(engine=sim.engine.name, slope_deg=args.slope, controller=controller)
    return summary


def _join(args: argparse.Namespace):
    """The processes that run the learners together (``mjxcpg.jaxutil.processes``): this one
    alone unless a flag asks for several, before anything else touches JAX."""
    from mjxcpg.jaxutil import processes

    if not (args.distributed or args.coordinator or args.num_processes or args.process_id is not None):
        return processes.ALONE
    return processes.join(args.coordinator, args.num_processes, args.process_id, args.join_timeout)


def _learn_or_sweep(spec, args, out: Path) -> dict | None:
    """Run (or resume) ``spec`` in ``out`` and write its report, ``out`` locked meanwhile;
    None in a process other than 0 of several (``args.group``), which writes nothing."""
    from mjxcpg import api

    return api.sweep(spec, out, args.engine, resume=args.resume, force=args.force, progress=not args.quiet,
                     tensorboard=args.tensorboard, allow_other_code=args.allow_other_code, processes=args.group,
                     checkpoint_every_s=args.checkpoint_every)


def cmd_learn(args: argparse.Namespace) -> dict | None:
    args.group = _join(args)
    from mjxcpg.robots import DEFAULT_PLATFORM
    from mjxcpg.training.config import validate
    from mjxcpg.training.files import write_text_atomic
    from mjxcpg.training.runs import locked
    from mjxcpg.training.train import RunSpec

    if args.from_run is not None:
        if args.group.count > 1:
            raise UserError("--from runs in one process: leave out the flags of several processes")
        return _learn_online(args)
    if (args.robot != "nominal" or args.reward is not None or not args.learning or args.start is not None
            or args.exploration is not None):
        raise UserError("--robot, --reward, --start, --exploration and --no-learning need --from: learning from "
                        "scratch runs on the nominal robot")
    args.k_s = 10.0 if args.k_s is None else args.k_s
    args.seed = 0 if args.seed is None else args.seed
    spec = RunSpec.for_platform(args.platform or DEFAULT_PLATFORM, k_s=(args.k_s,), seeds=(args.seed,))
    spec = validate(dataclasses.replace(spec, trial=dataclasses.replace(
        spec.trial, max_trials=1000 if args.trials is None else args.trials)))
    out = Path(args.out or f"runs/learn_ks{args.k_s:g}_seed{args.seed}")
    summary = _learn_or_sweep(spec, args, out)
    if summary is None:
        return None
    learn_path = out / "learn.json"
    with locked(out):  # the run's files, renamed and added to
        if learn_path.is_file():  # a finished run, resumed: its record stays as it is
            result = json.loads(learn_path.read_text())
        else:
            learner = summary["learners"][0]
            returns = json.loads((out / "returns.json").read_text())[0]
            result = {"succeeded": learner["succeeded"], "trials_to_success": learner["trials_to_success"],
                      "trials": learner["trials"], "mean_vx": learner["mean_vx"],
                      "final_policy_fell": learner["final_policy_fell"],
                      "policy_input_gradient": learner["policy_input_gradient"],
                      "wall_s": summary["wall_s"], "engine": summary["engine"], "out": str(out),
                      "returns": returns["returns"], "falls": returns["falls"]}
            for name, short in ((f"learning_curve_ks{args.k_s:g}.png", "learning_curve.png"),
                                ("policy_map_00.png", "policy_map.png")):
                if (out / name).is_file():
                    (out / name).replace(out / short)
            write_text_atomic(learn_path, json.dumps(result, indent=1))
    return {k: v for k, v in result.items() if k not in ("returns", "falls")}


def _learn_online(args: argparse.Namespace) -> dict:
    """``learn --from DIR --learner K``: continue that learner on ``--robot`` (mjxcpg.evaluation.online)."""
    from mjxcpg.evaluation import online
    from mjxcpg.training.runs import CHECKPOINT_EVERY_S

    if args.k_s is not None or args.seed is not None or args.platform is not None:
        raise UserError("--k-s, --seed and --platform come from the checkpoint with --from")
    if args.resume or args.allow_other_code:
        raise UserError("--resume and --allow-other-code do not apply to --from; rerun with --force")
    if args.checkpoint_every != CHECKPOINT_EVERY_S:
        raise UserError("--checkpoint-every does not apply to --from, which saves its learner once, at the end")
    source = Path(args.from_run)
    args.start = args.start or "hand"
    name = "-".join(map(str, args.learner)) + ("" if args.learning else "_no_learning")
    out = Path(args.out or f"runs/online_{source.name}_learner{name}_{args.robot}")
    trials = 400 if args.trials is None else args.trials
    return online.learn_online(source, args.learner, out, trials=trials, robot=args.robot,
                               reward=args.reward, engine=args.engine, learning=args.learning, start=args.start,
                               exploration=args.exploration or "learned", force=args.force,
                               progress=not args.quiet, tensorboard=args.tensorboard) | {"out": str(out)}


def cmd_render(args: argparse.Namespace) -> dict:
    from mjxcpg.evaluation import render

    out = Path(args.out or Path(args.run) / "render")
    try:
        return render.render_gait(Path(args.run), args.learner, out, seconds=args.seconds,
                                  engine=args.engine, robot=args.robot, gif=args.gif, force=args.force)
    except render.RenderError as error:
        raise UserError(str(error)) from None


def cmd_sweep(args: argparse.Namespace) -> dict | None:
    args.group = _join(args)
    from mjxcpg.training.config import load_spec

    spec = load_spec(args.config, platform=args.platform)
    out = Path(args.out or f"runs/{Path(args.config).stem}")
    summary = _learn_or_sweep(spec, args, out)
    if summary is None:
        return None
    print((out / "table1.md").read_text())
    ok = sum(r["succeeded"] for r in summary["learners"])
    return {"out": str(out), "learners": len(summary["learners"]), "succeeded": ok,
            "wall_s": summary["wall_s"], "engine": summary["engine"]}


def cmd_controls(args: argparse.Namespace) -> dict:
    from mjxcpg.evaluation import controls

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
    result = transfer.walk_on_engines(Path(args.run), args.seconds, args.walks, args.force)
    for r in result["learners"]:
        print(transfer.row_line(r, args.walks))
    return {k: v for k, v in result.items() if k != "learners"} | {"out": str(Path(args.run) / "transfer.json")}


def cmd_eval(args: argparse.Namespace) -> dict:
    """``eval --run DIR``: velocity (Fig 7), return map (Fig 8), slopes and pushes of the run's
    final policies, all learners in one batch; JSON and PNG under OUT/eval, OUT/report.md."""
    from mjxcpg import api
    from mjxcpg.evaluation.registry import EVALUATIONS

    fields = ["seed", "hand_seconds"] + [o.field for e in EVALUATIONS for o in e.options]
    overrides = {name: getattr(args, name) for name in fields if getattr(args, name) is not None}
    if args.transfer_repeats is not None and args.robot == "nominal":
        raise UserError(f"--transfer-repeats applies to --robot {hardware_robots_text()} only")
    repeats = {} if args.transfer_repeats is None else {"transfer_repeats": args.transfer_repeats}
    progress = None if args.quiet else (lambda text: print(f"eval: {text}", file=sys.stderr, flush=True))
    return api.evaluate_policies(args.run, args.learner or None, args.engine, args.robot,
                                 api.EvalParams(**overrides),
                                 parts=[p for p in api.EVALUATIONS if p not in (args.skip or [])],
                                 out=args.out, progress=progress,
                                 force=args.force, **repeats)


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


def cmd_reproduce(args: argparse.Namespace) -> dict:
    """``reproduce``: the sweep, its controls, every evaluation, the hardware robot and online
    learning on it, and one report (what ``make run`` runs)."""
    from mjxcpg import api

    budget = api.ReproductionBudget(**{name: getattr(args, name) for name in api.BUDGET_FLAGS
                                       if getattr(args, name) is not None})
    out = Path(args.out or f"runs/{Path(args.config).stem}")
    result = api.reproduce(args.config, out, args.engine, budget, progress=not args.quiet)
    print((out / "table1.md").read_text())
    return result
