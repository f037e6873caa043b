"""What a gait does over a long walk: heading, speed, CPG amplitude and period, a_5, per window.

Walks each chosen final policy (its mean, no noise), or a control (``--controller hand``:
the hand-designed feedback; ``zero``: a_5 = 0), from standing for ``--seconds`` on the
run's engine, all in one batch, and prints per learner and per window of ``--window``
seconds (after the first ``--settle`` seconds, 2 by default):

* heading: the pelvis' yaw (degrees, positive to the left), at the window's end;
* v_x: the mean velocity along the world's +x, as eval's Fig 7 and the trials' reward
  measure it; v_head: the mean speed along the robot's own heading (the pelvis' forward
  axis projected on the floor); y: the lateral position at the window's end (m);
* amp z / amp x: the amplitude (half the peak-to-peak) of q1 - q2 and q5 - q6, the CPG
  outputs of eqs 4-7; period: the mean interval between upward zero crossings of q1 - q2;
* stride: v_head times the period, the distance a gait cycle covers (two steps);
* |a5|: the mean magnitude of the propulsive feedback; h: the mean pelvis height.

    NPROC=1 .venv/bin/python bench/long_walk.py runs/stats --learners 60 61 --seconds 100
    NPROC=1 .venv/bin/python bench/long_walk.py runs/stats --controller hand --seconds 100
    NPROC=1 .venv/bin/python bench/long_walk.py runs/stats --learners 60 --set h_heading=1 --slope 3
    NPROC=1 .venv/bin/python bench/long_walk.py runs/paper --controller hand --seconds 20 --robot harsh

With ``--json FILE`` every window of every learner is also written there.
"""

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxcpg.control import cpg
from mjxcpg.control.controller import after_hand_start, control_step, hand_feedback, split_feedback
from mjxcpg.control.sim import ROBOTS
from mjxcpg.control.walk import has_fallen, initial_controller
from mjxcpg.jaxutil import xla
from mjxcpg.learning.learner import policy_mean_feedback
from mjxcpg.physics.model import observe
from mjxcpg.training import runs


def record_walk(sim, task, weights, feedback, steps: int):
    """Per control period and robot: free-joint qpos (7), qvel (2), heading, CPG outputs (6),
    a_5, fallen, pelvis height."""
    layout, params, engine = sim.layout, sim.params, sim.engine

    def one_robot(cpg_state, sensors, w, step):
        obs = observe(layout, sensors)
        action = after_hand_start(params, obs, feedback(obs, w), step, 0)  # the hand_fade, if the run has one
        cpg_state, ctrl = control_step(params, layout, cpg_state, obs, action)
        return cpg_state, ctrl, split_feedback(action)[0], has_fallen(layout, obs), obs.height, obs.heading

    def body(carry, step):
        physics, cpg_state, fallen = carry
        sensors = engine.sensors(physics)
        cpg_state, ctrl, a5, fell, height, heading = jax.vmap(one_robot, (0, 0, 0, None))(cpg_state, sensors, weights,
                                                                                         step)
        fallen = fallen | fell
        physics = engine.step(physics, ctrl, ~fallen)
        row = (sensors.qpos[:, :7], sensors.qvel[:, :2], heading, cpg.output(cpg_state.cpg), a5, fallen, height)
        return (physics, cpg_state, fallen), row

    @xla.jit
    def walk():
        batch = jax.tree.leaves(weights)[0].shape[0]
        carry = (engine.init(sim.qpos0, batch), initial_controller(batch), jnp.zeros(batch, bool))
        return jax.lax.scan(body, carry, jnp.arange(steps))[1]

    return [np.asarray(x) for x in jax.device_get(walk())]


def windows(rows, k: int, dt: float, window_s: float, settle_s: float = 2.0) -> list[dict]:
    qpos, qvel, heading_rad, q, a5, fallen, height = (r[:, k] for r in rows)
    yaw = np.unwrap(heading_rad)
    heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    v_head = np.sum(qvel * heading, axis=1)
    stepping, propulsion = q[:, 0] - q[:, 1], q[:, 4] - q[:, 5]
    per = round(window_s / dt)
    out = []
    for start in range(round(settle_s / dt), len(yaw) - per + 1, per):
        s = slice(start, start + per)
        if fallen[s].any():
            out.append({"t0": start * dt, "fell": True})
            break
        sway = stepping[s] - stepping[s].mean()
        up = np.flatnonzero((sway[:-1] < 0) & (sway[1:] >= 0))
        out.append({
            "t0": start * dt, "fell": False, "heading_deg": float(np.degrees(yaw[s][-1])),
            "vx": float((qpos[s][-1, 0] - qpos[s][0, 0]) / ((per - 1) * dt)),
            "v_head": float(np.mean(v_head[s])), "y": float(qpos[s][-1, 1]),
            "amp_z": float(np.ptp(stepping[s]) / 2), "amp_x": float(np.ptp(propulsion[s]) / 2),
            "period": float(np.mean(np.diff(up)) * dt) if len(up) > 2 else None,
            "stride": float(np.mean(v_head[s]) * np.mean(np.diff(up)) * dt) if len(up) > 2 else None,
            "abs_a5": float(np.mean(np.abs(a5[s]))), "height": float(np.mean(height[s]))})
    return out


LAST_WINDOWS = 4  # "the end of the walk": its last four windows (the last 40 s of 100 s)


def overview(run: Path, spec, results: dict) -> list[str]:
    """Over the policies walked: falls, those whose end is below 80% of their speed in the
    run's own 20 s walk (summary.json), the largest heading, the k_s = 10 means."""
    trial_vx = {r["learner"]: r["mean_vx"] for r in json.loads((run / "summary.json").read_text())["learners"]}
    fell = [k for k, ws in results.items() if any(w["fell"] for w in ws)]
    walked = {k: ws for k, ws in results.items() if k not in fell}
    end_vx = {k: float(np.mean([w["vx"] for w in ws[-LAST_WINDOWS:]])) for k, ws in walked.items()}
    slow = [k for k in walked if spec.k_s[k] >= 1 and end_vx[k] < 0.8 * trial_vx[k]]
    largest = {k: max(abs(w["heading_deg"]) for w in ws) for k, ws in walked.items()}
    top = [k for k in walked if spec.k_s[k] == max(spec.k_s)]
    lines = [f"fell: {len(fell)} of {len(results)} {fell}",
             f"k_s >= 1 below 80% of the 20 s walk's speed over the last {LAST_WINDOWS} windows: "
             f"{len(slow)} of {sum(spec.k_s[k] >= 1 for k in results)} {slow}"]
    if largest:
        lines.append(f"largest |heading| (deg): median {np.median(list(largest.values())):.1f}, "
                     f"max {max(largest.values()):.1f}")
    if top:
        lines.append(f"k_s = {max(spec.k_s):g}: mean v_x at the end {np.mean([end_vx[k] for k in top]):.4f} m/s, "
                     f"in the 20 s walk {np.mean([trial_vx[k] for k in top]):.4f}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--learners", type=int, nargs="+", default=None, help="default: all")
    parser.add_argument("--controller", choices=("policy", "hand", "zero"), default="policy")
    parser.add_argument("--seconds", type=float, default=100.0)
    parser.add_argument("--window", type=float, default=10.0)
    parser.add_argument("--settle", type=float, default=2.0, help="seconds left out before the first window")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                        help="controller constants instead of the run's (ControllerParams fields)")
    parser.add_argument("--slope", type=float, default=0.0, help="floor slope (degrees, uphill > 0)")
    parser.add_argument("--robot", choices=ROBOTS, default="nominal", help="the robot walked (docs/hardware.md)")
    args = parser.parse_args()
    spec, sim, task, state = runs.load_run(args.run)
    changes = {name: float(value) for name, value in (item.split("=", 1) for item in args.set)}
    sim = sim.rebuild(params=dataclasses.replace(sim.params, **changes), slope_deg=args.slope, robot=args.robot)
    chosen = runs.check_learners(spec, args.learners)
    weights = jax.tree.map(lambda w: w[np.asarray(chosen)], state.learners.weights)
    feedback = {"policy": policy_mean_feedback(task),
                "hand": lambda obs, w: hand_feedback(sim.params, obs),
                "zero": lambda obs, w: jnp.zeros_like(obs.gyro[0])}[args.controller]
    rows = record_walk(sim, task, weights, feedback, round(args.seconds / sim.control_dt))
    results = {}
    for j, learner in enumerate(chosen):
        results[learner] = windows(rows, j, sim.control_dt, args.window, args.settle)
        print(f"\nlearner {learner} (k_s = {spec.k_s[learner]:g}, seed {spec.seeds[learner]}), {args.controller}")
        print("| t (s) | heading (deg) | v_x | v_head | y (m) | amp z | amp x | period (s) | stride (m) | abs a5 | h (m) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for w in results[learner]:
            if w["fell"]:
                print(f"| {round(w['t0'], 3):g} | fell | | | | | | | | | |")
                continue
            period = f"{w['period']:.3f}" if w["period"] else "-"
            stride = f"{w['stride']:.4f}" if w["stride"] else "-"
            print(f"| {round(w['t0'], 3):g} | {w['heading_deg']:+.1f} | {w['vx']:.4f} | {w['v_head']:.4f} | {w['y']:+.3f} "
                  f"| {w['amp_z']:.3f} | {w['amp_x']:.3f} | {period} | {stride} | {w['abs_a5']:.3f} | {w['height']:.4f} |")
    if (args.run / "summary.json").is_file() and args.controller == "policy":
        print("\n" + "\n".join(overview(args.run, spec, results)))
    if args.json:
        args.json.write_text(json.dumps({str(k): v for k, v in results.items()}, indent=1))


if __name__ == "__main__":
    try:
        main()
    except runs.RunError as error:
        raise SystemExit(f"long_walk: {error}") from None
