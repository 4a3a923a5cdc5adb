"""Figures: error vs trial (like Fig. 7), trajectories against the formation (like Fig. 6).

matplotlib is imported here only, so the simulator starts fast without plots.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["plot_errors", "plot_trajectories", "plot_compare"]


def _plt():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_errors(trials: NDArray[np.float64], pos: NDArray[np.float64],
                head: NDArray[np.float64], path: Path, title: str,
                per_robot: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
                targets: tuple[float, float] | None = None) -> Path:
    """Max position [m] and heading [rad] error per trial, log scale (the team's: black).

    per_robot : (trials, errors of shape (K, N, 2)): each robot's own curve, thin and
    coloured, labelled "robot i". targets : the levels [m, rad] drawn as dashed lines
    (default ``TARGET_POSITION``, ``TARGET_HEADING``): where the team has learned.
    """
    from formation_ilc.core.metrics import TARGET_HEADING, TARGET_POSITION

    plt = _plt()
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    if per_robot is not None and len(per_robot[0]):
        k, e = per_robot
        colors = plt.cm.tab10(np.arange(e.shape[1]) % 10)
        for i in range(e.shape[1]):
            for a, col in ((ax[0], 0), (ax[1], 1)):
                a.semilogy(k, e[:, i, col], color=colors[i], lw=0.9, zorder=3,
                           label=f"robot {i + 1}" if e.shape[1] <= 10 else None)
    # the team's curve under the robots' (it is the highest of them at every trial)
    ax[0].semilogy(trials, pos, color="k", lw=2.2, alpha=0.45, zorder=2,
                   label="team (max over robots)")
    ax[1].semilogy(trials, head, color="k", lw=2.2, alpha=0.45, zorder=2,
                   label="team (max over robots)")
    tp, th = targets if targets is not None else (TARGET_POSITION, TARGET_HEADING)
    ax[0].axhline(tp, color="0.25", ls="--", lw=1, label=f"target {tp:g} m")
    ax[1].axhline(th, color="0.25", ls="--", lw=1, label=f"target {th:g} rad")
    ax[0].set_ylabel("max position error [m]")
    ax[1].set_ylabel("max heading error [rad]")
    ax[1].set_xlabel("trial (from 0, as in metrics.csv)")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7, ncol=3, loc="upper right")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_compare(curves: Mapping[str, tuple[NDArray[np.float64], NDArray[np.float64],
                                            NDArray[np.float64]]],
                 path: Path, title: str) -> Path:
    """Several runs in one figure: {label: (trials, pos, head)}."""
    plt = _plt()
    fig, ax = plt.subplots(2, 1, figsize=(9, 7), sharex=True)
    styles = {"9": "k", "22": "tab:blue", "23": "tab:red"}
    for label, (k, p, h) in curves.items():
        color = styles.get(label.split()[0].strip("()law "), None)
        ls = "--" if "literal" in label else "-"
        ax[0].semilogy(k, p, ls, color=color, lw=1, label=label)
        ax[1].semilogy(k, h, ls, color=color, lw=1, label=label)
    ax[0].set_ylabel("max position error [m]")
    ax[1].set_ylabel("max heading error [rad]")
    ax[1].set_xlabel("trial")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    ax[0].legend(fontsize=8, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_trajectories(eta_d: NDArray[np.float64], runs: Mapping[int, NDArray[np.float64]],
                      path: Path, title: str, snapshots: Sequence[int] = (),
                      edges: Sequence[tuple[int, int]] = ()) -> Path:
    """Measured paths of chosen trials against the desired formation.

    eta_d : shape (N, T+1, 3); runs : {trial: eta, shape (N, T+1, 3)}. One panel per trial;
    desired paths dashed, formation drawn at the snapshot samples.
    """
    plt = _plt()
    k = max(1, len(runs))
    cols = min(k, 3)
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.4 * rows), squeeze=False)
    n, m, _ = eta_d.shape
    snaps = list(snapshots) or [0, m // 4, m // 2, 3 * m // 4, m - 1]
    colors = plt.cm.tab10(np.arange(n) % 10)
    for ax, (trial, eta) in zip(axes.flat, runs.items(), strict=False):
        for i in range(n):
            ax.plot(eta_d[i, :, 0], eta_d[i, :, 1], "--", color=colors[i], lw=0.8, alpha=0.6)
            ax.plot(eta[i, :, 0], eta[i, :, 1], "-", color=colors[i], lw=1.0,
                    label=f"robot {i + 1}")
        for t in snaps:
            for i, j in edges:
                ax.plot([eta_d[i, t, 0], eta_d[j, t, 0]], [eta_d[i, t, 1], eta_d[j, t, 1]],
                        ":", color="0.5", lw=0.8)
                ax.plot([eta[i, t, 0], eta[j, t, 0]], [eta[i, t, 1], eta[j, t, 1]], "-",
                        color="0.2", lw=0.8)
            ax.plot(eta[:, t, 0], eta[:, t, 1], "o", color="0.2", ms=2.5)
        ax.set_title(f"trial {trial}")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    for ax in list(axes.flat)[len(runs):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7, loc="best")
    fig.suptitle(title + "  (dashed: desired; grey: formation at snapshots)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
