"""The parser of ``mjxcpg``: subcommands, their options and the checks of their values."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import mjxcpg
from mjxcpg.cli.commands import (cmd_bench, cmd_controls, cmd_eval, cmd_learn, cmd_render, cmd_reproduce,
                                 cmd_sweep, cmd_transfer, cmd_walk, hardware_robots_text)
from mjxcpg.training import checks

DESCRIPTION = "The mjxcpg command line: reproduce, walk, learn, sweep, controls, transfer, eval, render, bench."


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``--help`` still shows the usage)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _number(rule: checks.Range) -> Callable[[str], int | float]:
    """An argparse type: the flag's text as a number that ``rule`` allows (``mjxcpg.training.checks``)."""
    def parse(text: str) -> int | float:
        try:
            return checks.parse(text, rule)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None

    return parse


def _exploration(text: str) -> str | float:
    """An argparse type: the flag's text as an online exploration (``online.parse_exploration``)."""
    from mjxcpg.evaluation.online import parse_exploration

    try:
        return parse_exploration(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def build_parser() -> argparse.ArgumentParser:
    from mjxcpg.control.sim import ROBOTS
    from mjxcpg.robots import PLATFORMS
    from mjxcpg.evaluation.protocol import EvalParams
    from mjxcpg.evaluation.registry import EVALUATIONS
    from mjxcpg.physics.engines import ENGINES
    from mjxcpg.physics.model import MAX_SLOPE_DEG
    from mjxcpg.training.config import config_names, range_of
    from mjxcpg.evaluation.controls import CONTROLS
    from mjxcpg.evaluation.online import REWARD_SOURCES, STARTS
    from mjxcpg.training.runs import CHECKPOINT_EVERY_S

    seconds = _number(checks.POSITIVE)
    non_negative = _number(checks.NON_NEGATIVE)
    count = _number(checks.COUNT)
    index = _number(checks.INDEX)
    slope = _number(checks.Range(low=-MAX_SLOPE_DEG, high=MAX_SLOPE_DEG))

    parser = _Parser(prog="mjxcpg", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"%(prog)s {mjxcpg.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    from mjxcpg.api import ReproductionBudget

    budget = ReproductionBudget()
    rep = sub.add_parser("reproduce", help="the paper from learning to its last figure, into one report "
                         "(make run): sweep, controls, eval, hardware robot, online learning")
    rep.add_argument("--config", default="paper",
                     help=f"the sweep's config ({', '.join(config_names())} or a .toml/.json path; default paper)")
    rep.add_argument("--out", help="run directory (default: runs/CONFIG)")
    rep.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
    rep.add_argument("--control-trials", type=count, default=None,
                     help=f"trial budget of each control learner (default {budget.control_trials})")
    rep.add_argument("--transfer-repeats", type=count, default=None,
                     help=f"walks per policy on each hardware robot (default {budget.transfer_repeats})")
    rep.add_argument("--online-robot", choices=ROBOTS[1:], default=None,
                     help=f"the hardware robot of online learning (default {budget.online_robot}; docs/hardware.md)")
    rep.add_argument("--online-start", choices=STARTS, default=None,
                     help=f"how online trials start (default {budget.online_start})")
    rep.add_argument("--online-exploration", type=_exploration, default=None, metavar="{learned,initial,SIGMA}",
                     help=f"the sigma online learning starts from: as learned, its initial value or SIGMA "
                          f"(from 1e-6 to 1 - 1e-6; default {budget.online_exploration})")
    rep.add_argument("--online-learners", type=_number(checks.NON_NEGATIVE_COUNT), default=None,
                     help=f"at most this many failing policies learn on that robot (default "
                          f"{budget.online_learners})")
    rep.add_argument("--online-trials", type=count, default=None,
                     help=f"trial budget of online learning (default {budget.online_trials})")
    rep.add_argument("--quiet", action="store_true", help="no progress lines")
    rep.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    rep.set_defaults(handler=cmd_reproduce)

    walk = sub.add_parser("walk", help="walk with a controller and report the gait")
    walk.add_argument("--controller", choices=("hand", "stepping", "in-place"), default=None,
                      help="hand (default): hand-designed a_5; stepping: a_5 = 0; in-place: a_5 = 0 and A_x = 0; "
                           "not with --checkpoint, which walks the run's own feedback")
    walk.add_argument("--checkpoint", help="walk with the learned policy saved in this run directory")
    walk.add_argument("--learner", type=index, default=0, help="learner index within a sweep checkpoint")
    walk.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
    walk.add_argument("--seconds", type=seconds, default=20.0)
    walk.add_argument("--slope", type=slope, default=0.0, help="floor slope in degrees (uphill > 0)")
    walk.add_argument("--platform", choices=tuple(PLATFORMS), default=None,
                      help="the robot (default qrio); with --checkpoint, the run's")
    walk.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    walk.set_defaults(handler=cmd_walk)

    def run_options(p: argparse.ArgumentParser) -> None:
        p.add_argument("--engine", choices=ENGINES, default=None, help="default: native on CPU, mjx on GPU/TPU")
        p.add_argument("--out", help="run directory (default: runs/...)")
        p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
        p.add_argument("--force", action="store_true", help="replace an existing --out")
        p.add_argument("--allow-other-code", action="store_true",
                       help="with --resume: continue a run made by other code (recorded in its config.json)")
        p.add_argument("--quiet", action="store_true", help="no progress line")
        p.add_argument("--no-tensorboard", dest="tensorboard", action="store_false",
                       help="write no TensorBoard event files (OUT/tensorboard)")
        p.add_argument("--checkpoint-every", metavar="SECONDS", type=non_negative,
                       default=CHECKPOINT_EVERY_S,
                       help=f"checkpoint after the first chunk this long after the last, and at the end "
                            f"(default {CHECKPOINT_EVERY_S:g}; 0: after every chunk)")
        p.add_argument("--json", action="store_true", help="print one JSON object as the last line")
        several = p.add_argument_group(
            "several processes", "run the learners in cooperating processes, on one host or many "
            "(docs/performance.md): every process runs the same command and checkpoints its own "
            "block of learners in --out, and process 0 writes the report; flags left out come from "
            "the environment as JAX reads it (JAX_COORDINATOR_ADDRESS, Slurm, Open MPI)")
        several.add_argument("--distributed", action="store_true",
                             help="join the other processes, everything from the environment")
        several.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address")
        several.add_argument("--num-processes", type=count, default=None, help="how many processes")
        several.add_argument("--process-id", type=index, default=None, help="this process, 0 to N-1")
        several.add_argument("--join-timeout", type=count, default=120,
                             help="seconds to wait for every process to join (default 120)")

    learn = sub.add_parser("learn", help="one learner learns the propulsive feedback a_5")
    learn.add_argument("--k-s", type=_number(range_of("k_s")), default=None, help="velocity reward gain k_S of eq 27 (default 10)")
    learn.add_argument("--seed", type=_number(range_of("seeds")), default=None, help="default 0")
    learn.add_argument("--trials", type=_number(range_of("trial.max_trials")), default=None,
                       help="trial budget (default 1000; 400 with --from)")
    learn.add_argument("--from", dest="from_run", metavar="DIR",
                       help="continue learner --learner of this run (online additional learning)")
    learn.add_argument("--learner", type=index, nargs="+", default=[0],
                       help="learner indices within --from's run, learning on together (default 0)")
    learn.add_argument("--no-learning", dest="learning", action="store_false",
                       help="with --from: the control, the same trials with every learning rate 0")
    learn.add_argument("--start", choices=STARTS, default=None,
                       help="with --from: hand (the run's hand-designed start, the default) or standing "
                            "(the policy from the first period)")
    learn.add_argument("--exploration", type=_exploration, default=None, metavar="{learned,initial,SIGMA}",
                       help="with --from: sigma starts as learned (the default), at its initial value or at "
                            "SIGMA (from 1e-6 to 1 - 1e-6)")
    learn.add_argument("--robot", choices=ROBOTS, default="nominal",
                       help=f"robot to continue on with --from ({hardware_robots_text()}: docs/hardware.md)")
    learn.add_argument("--reward", choices=REWARD_SOURCES, default=None,
                       help="with --from: reward from the robot's sensors (default on hardware) "
                            "or the simulator's state (default on nominal)")
    learn.add_argument("--platform", choices=tuple(PLATFORMS), default=None,
                       help="the robot that learns from scratch (default qrio; with --from, the run's)")
    run_options(learn)
    learn.set_defaults(handler=cmd_learn)

    sweep = sub.add_parser("sweep", help="many learners in lockstep (the paper's Table 1)")
    sweep.add_argument("--config", default="paper",
                       help=f"a config that ships with mjxcpg ({', '.join(config_names())}) or a .toml/.json path")
    sweep.add_argument("--platform", choices=tuple(PLATFORMS), default=None,
                       help="the robot, in place of the config's platform key (default qrio)")
    run_options(sweep)
    sweep.set_defaults(handler=cmd_sweep)

    ctl = sub.add_parser("controls", help="the run's protocol without learning, without a_5, and with "
                         "the hand-designed feedback, beside its Table 1")
    ctl.add_argument("--run", required=True, help="a finished sweep's run directory")
    ctl.add_argument("--trials", type=count, default=None,
                     help="trial budget of each control learner (default 400, at most the run's)")
    ctl.add_argument("--only", nargs="+", choices=tuple(CONTROLS), help="run only these controls")
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
    tr.add_argument("--seconds", type=seconds, default=20.0)
    tr.add_argument("--walks", type=count, default=8,
                    help="walks per policy: as learned, then with its weights moved by 1e-6 of themselves")
    tr.add_argument("--force", action="store_true", help="replace the run's earlier transfer.json")
    tr.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    tr.set_defaults(handler=cmd_transfer)

    rend = sub.add_parser("render", help="filmstrip PNG and MP4 video of a learned gait (headless OpenGL)")
    rend.add_argument("--run", required=True, help="run directory")
    rend.add_argument("--learner", type=index, default=0, help="learner index within the run")
    rend.add_argument("--seconds", type=seconds, default=10.0, help="length of the walk")
    rend.add_argument("--robot", choices=ROBOTS, default="nominal")
    rend.add_argument("--engine", choices=ENGINES, default=None, help="default: the run's")
    rend.add_argument("--out", help="output directory (default: RUN/render)")
    rend.add_argument("--gif", action="store_true", help="also write the video's frames as an animated GIF")
    rend.add_argument("--force", action="store_true", help="replace an earlier render of this learner and robot")
    rend.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    rend.set_defaults(handler=cmd_render)

    evaluation = sub.add_parser("eval", help="evaluate a run's learned policies as the paper did "
                                "(velocity, return map, slopes, pushes)")
    evaluation.add_argument("--run", required=True, help="run directory (learn or sweep)")
    evaluation.add_argument("--learner", type=index, nargs="+", help="learner indices (default: all)")
    evaluation.add_argument("--engine", choices=ENGINES, default=None, help="default: the run's")
    evaluation.add_argument("--robot", choices=ROBOTS, default="nominal", help="robot the policies walk on")
    evaluation.add_argument("--seed", type=_number(checks.SEED), default=None,
                            help=f"seed of the perturbations and, with --robot {hardware_robots_text()}, of the sensor noise "
                                 "(default 0)")
    evaluation.add_argument("--hand-seconds", type=_number(checks.NON_NEGATIVE), default=None,
                            help="hand-designed feedback first for this long, as at a learning trial's start "
                                 "(default 0: each policy from standing)")
    defaults = EvalParams()
    for registered in EVALUATIONS:
        for option in registered.options:
            evaluation.add_argument(option.flag, type=_number(option.rule), default=None,
                                    help=f"{option.help} (default {getattr(defaults, option.field):g})")
    only_on = "; ".join(f"{e.name}: --robot {' or '.join(e.robots)} only" for e in EVALUATIONS if e.robots)
    evaluation.add_argument("--skip", nargs="+", choices=tuple(e.name for e in EVALUATIONS),
                            help=f"evaluations to leave out ({only_on})")
    evaluation.add_argument("--transfer-repeats", type=count, default=None,
                            help=f"with --robot {hardware_robots_text()} only: walks per policy, each with other sensor noise "
                                 "(default 20)")
    evaluation.add_argument("--out", help="write eval/ and report.md here (default: the run directory; "
                                           f"with --robot {hardware_robots_text()}, its subdirectory of that name)")
    evaluation.add_argument("--force", action="store_true", help="replace an earlier evaluation in OUT")
    evaluation.add_argument("--quiet", action="store_true", help="no progress lines")
    evaluation.add_argument("--json", action="store_true", help="print one JSON object as the last line")
    evaluation.set_defaults(handler=cmd_eval)

    from mjxcpg import bench

    bench_parser = sub.add_parser("bench", help="robot-steps/s of every engine, batch size, model and "
                                  "workload, side by side (bench/README.md)")
    bench_parser.add_argument("--engines", nargs="+", choices=ENGINES, default=list(ENGINES))
    bench_parser.add_argument("--models", nargs="+", choices=bench.MODELS, default=list(bench.MODELS),
                              help="qrio: our robot; humanoid: MJX's benchmark model (physics only)")
    bench_parser.add_argument("--batches", nargs="+", type=count, default=list(bench.BATCHES),
                              help="robots stepped together")
    bench_parser.add_argument("--workloads", nargs="+", choices=bench.WORKLOADS, default=list(bench.WORKLOADS),
                              help="physics: physics alone; full: physics + controller + learner")
    bench_parser.add_argument("--seconds", type=seconds, default=bench.Options.seconds,
                              help="timed seconds per measurement, after a warm-up call")
    bench_parser.add_argument("--budget-seconds", type=seconds, default=bench.Options.budget_seconds,
                              help="stepping time a measurement may take (compilation apart); "
                                   "cases projected past it are skipped")
    bench_parser.add_argument("--control-steps", type=count, default=bench.Options.control_steps,
                              help="control periods per timed call")
    bench_parser.add_argument("--quiet", action="store_true", help="no progress lines")
    bench_parser.add_argument("--json", action="store_true",
                              help="print the report as one JSON object, the last line of stdout")
    bench_parser.set_defaults(handler=cmd_bench)
    return parser
