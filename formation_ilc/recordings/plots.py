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
                head: NDArray[np.float64], path: Path, title: str) -> Path:
    """Max position [m] and heading [rad] error per trial, log scale."""
    plt = _plt()
    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax[0].semilogy(trials, pos, color="k", lw=1)
    ax[0].set_ylabel("max position error [m]")
    ax[1].semilogy(trials, head, color="k", lw=1)
    ax[1].set_ylabel("max heading error [rad]")
    ax[1].set_xlabel("trial")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
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
