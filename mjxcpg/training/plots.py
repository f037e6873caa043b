"""A run's figures, as PNG: learning curves (Fig 4), policy maps (Fig 5), learning diagnostics."""

from __future__ import annotations

from pathlib import Path

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mjxcpg.learning import ngnet, policy  # noqa: E402


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
