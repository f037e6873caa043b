"""Every figure mjxcpg draws, as PNG: learning curves (Fig 4), policy maps (Fig 5) and learning
diagnostics of a run; velocity against k_s (Fig 7), return maps and their eigenvalues (Fig 8),
slope ranges and push impulses of its evaluation."""

from __future__ import annotations

from pathlib import Path

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mjxcpg.learning import ngnet, policy  # noqa: E402
from mjxcpg.training import stats  # noqa: E402


def save_figure(fig, path: Path) -> None:
    """Write ``fig`` as a PNG and free it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def learning_curves(results: list[dict], path: Path, title: str = "") -> None:
    """Accumulated reward per trial, one line per learner, with a 20-trial running mean."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        returns = np.asarray(r["returns"])
        if len(returns) == 0:
            continue
        line, = ax.plot(returns, alpha=0.25, lw=0.8)
        window = min(20, len(returns))
        mean = np.convolve(returns, np.ones(window) / window, mode="valid")
        ax.plot(np.arange(window - 1, len(returns)), mean, color=line.get_color(),
                label=f"k_s={r['k_s']:g} seed={r['seed']}")
    ax.set_xlabel("trial")
    ax.set_ylabel("accumulated reward")
    ax.set_title(title or "Learning curve (cf. Fig 4)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def policy_map(mean_weights: np.ndarray, basis: ngnet.NGnetBasis, a_max: float, path: Path,
               title: str = "", v_scale: float = 1.0) -> None:
    """The policy's mean feedback a_max g(mu(x) / v_scale) over (d theta_roll/dt, d theta_pitch/dt)."""
    axis = np.linspace(-2, 2, 61)
    roll, pitch = np.meshgrid(axis, axis, indexing="xy")
    x = np.stack([roll.ravel(), pitch.ravel()], axis=-1)
    mean = jax.vmap(lambda xi: ngnet.ngnet_value(mean_weights, ngnet.normalized_basis(basis, xi)))(x)
    a5 = np.asarray(policy.feedback_action(mean, a_max, v_scale)).reshape(roll.shape)
    fig, ax = plt.subplots(figsize=(5, 4))
    mesh = ax.pcolormesh(roll, pitch, a5, cmap="coolwarm", vmin=-a_max, vmax=a_max, shading="auto")
    fig.colorbar(mesh, ax=ax, label="a_5 (policy mean)")
    ax.set_xlabel("d theta_roll/dt (rad/s)")
    ax.set_ylabel("d theta_pitch/dt (rad/s)")
    ax.set_title(title or "Learned policy (cf. Fig 5)")
    save_figure(fig, path)


def input_dominance(mean_weights: np.ndarray, basis: ngnet.NGnetBasis) -> dict:
    """Mean |d mu / d input| over the grid for each input: which input the policy uses."""
    axis = np.linspace(-1.5, 1.5, 31)
    x = np.stack(np.meshgrid(axis, axis, indexing="xy"), axis=-1).reshape(-1, 2)
    grad = jax.vmap(jax.grad(lambda xi: ngnet.ngnet_value(mean_weights, ngnet.normalized_basis(basis, xi))))(x)
    g = np.abs(np.asarray(grad)).mean(axis=0)
    return {"roll_rate": float(g[0]), "pitch_rate": float(g[1])}


def diagnostics(results: list[dict], path: Path, window: int = 20) -> None:
    """Per k_s, over trials: the median and the 10th-90th percentile band over learners of the
    trial's mean velocity after the hand-over, the policy's sigma, the fall rate (running mean
    over ``window`` trials) and the mean |a_5|."""
    panels = (("velocities", "mean velocity after hand-over (m/s)"), ("sigmas", "sigma"),
              ("falls", f"fall rate (running mean of {window})"), ("mean_abs_a5", "mean |a_5|"))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    for k_s in sorted({r["k_s"] for r in results}):
        group = [r for r in results if r["k_s"] == k_s and r["trials"] > 0]
        if not group:
            continue
        length = max(r["trials"] for r in group)
        for ax, (key, label) in zip(axes.ravel(), panels):
            rows = np.full((len(group), length), np.nan)
            for i, r in enumerate(group):
                values = np.asarray(r[key], float)
                if key == "falls":  # the mean over the last ``window`` trials, or all so far
                    total = np.cumsum(values)
                    total[window:] -= total[:-window]
                    values = total / np.minimum(np.arange(1, len(values) + 1), window)
                rows[i, :len(values)] = values
            trial = np.arange(1, length + 1)
            low, mid, high = np.nanpercentile(rows, [10, 50, 90], axis=0)
            line, = ax.plot(trial, mid, lw=1, label=f"k_s={k_s:g}")
            ax.fill_between(trial, low, high, color=line.get_color(), alpha=0.15, lw=0)
            ax.set_ylabel(label)
    for ax in axes[1]:
        ax.set_xlabel("trial")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Learning diagnostics per k_s: median and 10-90th percentiles over learners")
    save_figure(fig, path)

def _ks_jitter(rows: list[dict]) -> np.ndarray:
    """k_s of each row, spread a little within a k_s so that equal values stay visible."""
    ks = np.array([r["k_s"] for r in rows], float)
    offsets = np.zeros_like(ks)
    for value in np.unique(ks):
        idx = np.flatnonzero(ks == value)
        offsets[idx] = (np.arange(len(idx)) - (len(idx) - 1) / 2) * 0.08
    return ks + offsets


def velocity_vs_ks(rows: list[dict], path: Path, reference: float | None = None) -> None:
    """Fig 7: each final policy's mean walking velocity against its k_s (hollow: learning
    did not succeed or the policy fell), with the mean of the walking successful ones per k_s
    and its 95% bootstrap interval over them."""
    fig, ax = plt.subplots(figsize=(6, 4))
    x = _ks_jitter(rows)
    for xi, r in zip(x, rows):
        v, ok = r["return_map"]["mean_vx"], r["succeeded"] and not r["return_map"]["fell"]
        if v is None or not np.isfinite(v):
            continue
        ax.plot(xi, v, "o", color="C0", mfc="C0" if ok else "none")
    means = {}
    for r in rows:
        v = r["return_map"]["mean_vx"]
        if r["succeeded"] and not r["return_map"]["fell"] and v is not None and np.isfinite(v):
            means.setdefault(r["k_s"], []).append(v)
    if means:
        ks = sorted(means)
        estimates = [stats.mean_interval(means[k]) for k in ks]
        centre = np.array([e.value for e in estimates])
        spread = np.array([[e.value - e.low, e.high - e.value] if e.n > 1 else [0.0, 0.0] for e in estimates]).T
        ax.errorbar(ks, centre, yerr=spread, fmt="-", color="C1", capsize=3,
                    label="mean of successful policies, 95% bootstrap interval")
    if reference is not None:
        ax.axhline(reference, color="gray", ls=":", label=f"paper, Fig 6 gait ({reference} m/s)")
    ax.plot([], [], "o", color="C0", mfc="none", label="not learned, or fell")
    ax.set_xlabel("velocity reward gain k_s")
    ax.set_ylabel("mean walking velocity (m/s)")
    ax.set_title("Velocity vs velocity reward (cf. Fig 7)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def return_map(result: dict, path: Path, title: str = "") -> None:
    """Fig 8: x_{n+1} against x_n for the perturbed steps, their least-squares line, the
    identity, and the fixed point (white dot: the mean of the unperturbed steps)."""
    x, y = np.asarray(result["x_n"]), np.asarray(result["x_next"])
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    values = np.concatenate([x, y, [result["fixed_point"]]]) * 1000
    values = values[np.isfinite(values)]
    lo, hi = (values.min() - 2, values.max() + 2) if len(values) else (0, 1)
    ax.plot([lo, hi], [lo, hi], color="gray", lw=0.8, ls=":", label="x_{n+1} = x_n")
    ax.plot(x * 1000, y * 1000, "o", color="C0", ms=4, label=f"{len(x)} perturbed steps")
    if result["eigenvalue"] is not None:
        line = np.array([lo, hi])
        ax.plot(line, result["eigenvalue"] * line + result["intercept"] * 1000, color="C1",
                label=f"least squares: slope {result['eigenvalue']:.3f}")
    if result["fixed_point"] is not None and np.isfinite(result["fixed_point"]):
        fp = result["fixed_point"] * 1000
        ax.plot(fp, fp, "o", mfc="white", mec="black", ms=9,
                label=f"fixed point ({result['fixed_point_steps']} steps)")
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_xlabel("step length x_n (mm)")
    ax.set_ylabel("step length x_{n+1} (mm)")
    ax.set_title(title or "Return map of step length (cf. Fig 8)", fontsize=9)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def eigenvalues(rows: list[dict], path: Path, reference: float | None = None) -> None:
    """Every policy's return-map eigenvalue (with its standard error) against its k_s."""
    fig, ax = plt.subplots(figsize=(6, 4))
    x = _ks_jitter(rows)
    for xi, r in zip(x, rows):
        rm = r["return_map"]
        if rm["eigenvalue"] is None:
            continue
        ok = r["succeeded"] and not rm["fell"]
        ax.errorbar(xi, rm["eigenvalue"], yerr=rm["eigenvalue_stderr"] or 0, fmt="o", color="C0",
                    mfc="C0" if ok else "none", ms=5, capsize=2)
    ax.axhspan(-1, 1, color="C2", alpha=0.08, label="|eigenvalue| < 1: locally stable")
    ax.plot([], [], "o", color="C0", mfc="none", label="not learned, or fell")
    if reference is not None:
        ax.axhline(reference, color="gray", ls=":", label=f"paper ({reference})")
    ax.set_xlabel("velocity reward gain k_s")
    ax.set_ylabel("return-map eigenvalue")
    ax.set_title("Return-map eigenvalue of step length (cf. Fig 8)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def slope_ranges(rows: list[dict], path: Path, reference: tuple[float, float] | None = None) -> None:
    """Each policy's range of floor inclinations walked 20 s without a fall (bars), beside
    the paper's range (shaded)."""
    fig, ax = plt.subplots(figsize=(6, 0.3 * len(rows) + 1.5))
    if reference is not None:
        ax.axvspan(reference[1], reference[0], color="gray", alpha=0.15,
                   label=f"paper: {reference[0]:+g} to {reference[1]:+g} deg")
    for i, r in enumerate(rows):
        s = r["slopes"]
        if s["uphill_deg"] is None:
            ax.plot(0, i, "x", color="C3")
            continue
        ax.plot([s["downhill_deg"], s["uphill_deg"]], [i, i], "-", lw=5, solid_capstyle="butt",
                color="C0" if r["succeeded"] else "C7")
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([f"{r['learner']} (k_s={r['k_s']:g})" for r in rows], fontsize=7)
    ax.set_xlabel("floor inclination (deg, uphill > 0)")
    ax.set_title("Slopes walked for 20 s without a fall (x: falls on level ground)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def push_impulses(rows: list[dict], path: Path) -> None:
    """The largest survived pelvis impulse of each policy, per direction (hatched: capped,
    every impulse tried was survived)."""
    directions = list(rows[0]["pushes"]) if rows else []
    fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(rows) + 2), 4))
    width = 0.8 / max(len(directions), 1)
    for d, name in enumerate(directions):
        values = [r["pushes"][name]["impulse"] for r in rows]
        bars = ax.bar(np.arange(len(rows)) + d * width, values, width, label=name)
        for bar, r in zip(bars, rows):
            if r["pushes"][name]["capped"]:
                bar.set_hatch("//")
    ax.set_xticks(np.arange(len(rows)) + 0.4 - width / 2)
    ax.set_xticklabels([f"{r['learner']}\nk_s={r['k_s']:g}" for r in rows], fontsize=7)
    ax.set_ylabel("largest survived impulse (N s)")
    ax.set_title("Pushes on the pelvis at a left touchdown")
    ax.legend(fontsize=7)
    save_figure(fig, path)
