"""Figures: learning curves (Fig 4) and policy maps (Fig 5), as PNG."""

from __future__ import annotations

from pathlib import Path

import jax
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mjxcpg import ngnet, policy  # noqa: E402


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
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def policy_map(mean_weights: np.ndarray, basis: ngnet.NGnetBasis, a_max: float, path: Path,
               title: str = "") -> None:
    """The policy's mean feedback a_max g(mu(x)) over (d theta_roll/dt, d theta_pitch/dt)."""
    axis = np.linspace(-2, 2, 61)
    roll, pitch = np.meshgrid(axis, axis, indexing="xy")
    x = np.stack([roll.ravel(), pitch.ravel()], axis=-1)
    mean = jax.vmap(lambda xi: ngnet.ngnet_value(mean_weights, ngnet.normalized_basis(basis, xi)))(x)
    a5 = np.asarray(policy.feedback_action(mean, a_max)).reshape(roll.shape)
    fig, ax = plt.subplots(figsize=(5, 4))
    mesh = ax.pcolormesh(roll, pitch, a5, cmap="coolwarm", vmin=-a_max, vmax=a_max, shading="auto")
    fig.colorbar(mesh, ax=ax, label="a_5 (policy mean)")
    ax.set_xlabel("d theta_roll/dt (rad/s)")
    ax.set_ylabel("d theta_pitch/dt (rad/s)")
    ax.set_title(title or "Learned policy (cf. Fig 5)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def input_dominance(mean_weights: np.ndarray, basis: ngnet.NGnetBasis) -> dict:
    """Mean |d mu / d input| over the grid for each input: which input the policy uses."""
    axis = np.linspace(-1.5, 1.5, 31)
    x = np.stack(np.meshgrid(axis, axis, indexing="xy"), axis=-1).reshape(-1, 2)
    grad = jax.vmap(jax.grad(lambda xi: ngnet.ngnet_value(mean_weights, ngnet.normalized_basis(basis, xi))))(x)
    g = np.abs(np.asarray(grad)).mean(axis=0)
    return {"roll_rate": float(g[0]), "pitch_rate": float(g[1])}
