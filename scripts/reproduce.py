#!/usr/bin/env python3
"""Regenerate the runs, figures and numbers of docs/reproduction.md from scratch.

    .venv/bin/python scripts/reproduce.py [--runs DIR] [--seeds 1,2,3,4,5]

Every simulation is a ``formation-ilc`` CLI call (printed before it runs). The one
exception is the sim-to-real analogue of Fig. 14 (300 noise-free trials, then 25 noisy
trials that start from the learned memory): that step calls
``formation_ilc.model.simulate.simulate(initial_memory=...)`` (the CLI's ``--init-memory``).
Figures go to docs/figures/, numbers to docs/figures/numbers.json. About a minute.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CLI = str(ROOT / ".venv" / "bin" / "formation-ilc")
FIG = ROOT / "docs" / "figures"
DPI = 100


def run(args: list[str], log: Path | None = None) -> str:
    print("$ formation-ilc " + " ".join(args), flush=True)
    # one BLAS thread per run: the runs go in parallel, and threaded BLAS only slows the
    # lifted-map products of ``check`` down on a small machine
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    res = subprocess.run([CLI, *args], capture_output=True, text=True, env=env)
    # ``check`` answers with its verdict in the exit status (3 fails, 4 a large transient,
    # 5 map not built): a verdict is a result here, not a failure of the run
    verdicts = (0, 3, 4, 5) if args[0] == "check" else (0,)
    if res.returncode not in verdicts:
        raise subprocess.CalledProcessError(res.returncode, [CLI, *args], res.stdout,
                                            res.stderr)
    out = res.stdout
    if log is not None:
        log.write_text(out)
    return out


def run_all(jobs: list[tuple[list[str], Path | None]]) -> list[str]:
    """Independent CLI runs, as many at once as there are CPUs (output order kept)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=max(1, os.cpu_count() or 1)) as ex:
        return list(ex.map(lambda j: run(*j), jobs))


def read_metrics(path: Path) -> dict[str, np.ndarray]:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    head, data = rows[0], np.array(rows[1:], dtype=float)
    return {h: data[:, i] for i, h in enumerate(head)}


def settle(x: np.ndarray, level: float) -> int | None:
    """First trial from which the error stays below ``level`` to the end (None: never)."""
    above = np.flatnonzero(x >= level)
    if len(above) == 0:
        return 0
    k = int(above[-1]) + 1
    return k if k < len(x) else None


def stats(m: dict[str, np.ndarray], tail: int) -> dict[str, float | int | None]:
    p, h = m["max_position_error"], m["max_heading_error"]
    return {
        "first_pos": float(p[0]), "first_head": float(h[0]),
        "peak_pos": float(p.max()), "peak_pos_trial": int(p.argmax()),
        "last_pos": float(p[-1]), "last_head": float(h[-1]),
        "tail_median_pos": float(np.median(p[-tail:])),
        "tail_median_head": float(np.median(h[-tail:])),
        "tail_median_true_pos": float(np.median(m["true_max_position_error"][-tail:])),
        "tail_median_true_head": float(np.median(m["true_max_heading_error"][-tail:])),
        "tail_median_rms_pos": float(np.median(m["rms_position_error"][-tail:])),
        "min_pos": float(p.min()),
        "settle_pos_1m": settle(p, 1.0), "settle_pos_0.5m": settle(p, 0.5),
        "settle_head_0.1": settle(h, 0.1), "settle_head_0.03": settle(h, 0.03),
    }


LABELS = [("9", "feedforward"), ("9", "literal"), ("22", "feedforward"),
          ("23", "feedforward"), ("23", "literal")]
COLORS = {"9": "k", "22": "tab:blue", "23": "tab:red"}


def compare_metrics(d: Path) -> dict[str, dict[str, np.ndarray]]:
    return {f"({law}) {mem}": read_metrics(d / f"metrics_law{law}_{mem}.csv")
            for law, mem in LABELS}


def parse_check(text: str) -> dict[str, float]:
    num = r"([0-9.eE+-]+)"
    out = {}
    for key, pat in [("cond20", r"Gamma B\|\| = " + num),
                     ("cond20_no_dt", r"computed it: " + num),
                     ("lifted_norm", r"norm " + num + ","),
                     ("spectral_radius", r"spectral radius " + num),
                     ("max_power_norm", r"max \|\|M\^k\|\| = " + num),
                     ("max_power_k", r"at k = " + num),
                     ("start_growth", r"start error x" + num)]:
        mt = re.search(pat, text)
        if mt:
            out[key] = float(mt.group(1).rstrip(";,"))
    mt = re.search(r"verdict: (.*)", text)
    if mt:
        out["verdict"] = mt.group(1)  # type: ignore[assignment]
    return out


# ------------------------------------------------------------------------------ figures

def plt_():  # type: ignore[no-untyped-def]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, name: str) -> None:  # type: ignore[no-untyped-def]
    path = FIG / name
    fig.savefig(path, dpi=DPI)
    plt_().close(fig)
    try:  # palette PNG: a quarter of the size, no visible loss on line plots
        from PIL import Image

        im = Image.open(path).convert("RGB").quantize(colors=64, method=Image.MEDIANCUT)
        im.save(path, optimize=True)
    except ImportError:
        pass
    print(f"  {path.relative_to(ROOT)}  {path.stat().st_size / 1024:.0f} KB")


def plot_desired(sc, title: str, name: str, n_snap: int = 7) -> None:  # type: ignore[no-untyped-def]
    plt = plt_()
    eta, ref = sc.desired.eta, sc.desired.reference
    n, m, _ = eta.shape
    colors = plt.cm.tab10(np.arange(n))
    fig, ax = plt.subplots(figsize=(6.4, 6.0))
    ax.plot(ref[:, 0], ref[:, 1], "--", color="0.4", lw=1, label="leader r(t)")
    for i in range(n):
        ax.plot(eta[i, :, 0], eta[i, :, 1], color=colors[i], lw=1.1, label=f"robot {i + 1}")
    edges = ([(i, (i + 1) % n) for i in range(n)])
    for t in np.linspace(0, m - 1, n_snap).astype(int):
        for i, j in edges:
            ax.plot(eta[[i, j], t, 0], eta[[i, j], t, 1], "-", color="0.25", lw=0.7)
        ax.plot(eta[:, t, 0], eta[:, t, 1], "o", color="0.2", ms=2.5)
        ax.annotate(f"t={t}", (ref[t, 0], ref[t, 1]), fontsize=7, color="0.3")
    # moving direction of the leader
    for t in np.linspace(0, m - 2, 9).astype(int)[1:]:
        ax.annotate("", xy=(ref[t + 1, 0], ref[t + 1, 1]), xytext=(ref[t, 0], ref[t, 1]),
                    arrowprops=dict(arrowstyle="-|>", color="r", lw=1.2, mutation_scale=14))
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    save(fig, name)


def plot_trials(eta_d, runs: dict[str, np.ndarray], title: str, name: str,  # type: ignore[no-untyped-def]
                cols: int, err_panel: bool = True, xi_runs: dict[str, np.ndarray] | None = None
                ) -> None:
    plt = plt_()
    n, m, _ = eta_d.shape
    k = len(runs) + (1 if err_panel else 0)
    rows = int(np.ceil(k / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.3 * cols, 3.2 * rows), squeeze=False)
    colors = plt.cm.tab10(np.arange(n))
    snaps = np.linspace(0, m - 1, 5).astype(int)
    edges = [(i, (i + 1) % n) for i in range(n)]
    for ax, (lab, eta) in zip(axes.flat, runs.items(), strict=False):
        for i in range(n):
            ax.plot(eta_d[i, :, 0], eta_d[i, :, 1], "--", color=colors[i], lw=0.7, alpha=0.7)
            ax.plot(eta[i, :, 0], eta[i, :, 1], "-", color=colors[i], lw=0.9)
        for t in snaps:
            for i, j in edges:
                ax.plot(eta[[i, j], t, 0], eta[[i, j], t, 1], "-", color="0.2", lw=0.6)
        ax.set_title(lab, fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    if err_panel:
        ax = axes.flat[len(runs)]
        src = xi_runs if xi_runs is not None else runs
        for lab, xi in src.items():
            e = np.hypot(eta_d[:, 1:, 0] - xi[:, 1:, 0], eta_d[:, 1:, 1] - xi[:, 1:, 1]).max(0)
            ax.semilogy(np.arange(1, m), e, lw=0.9, label=lab.split(" (")[0])
        ax.set_xlabel("sample t", fontsize=8)
        ax.set_ylabel("max over robots of true\nposition error [m]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[k:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save(fig, name)


def plot_laws(cmps: dict[str, dict[str, dict[str, np.ndarray]]], seeds_band, title: str,  # type: ignore[no-untyped-def]
              name: str) -> None:
    """2 x 2: rows position / heading, columns feedforward / literal reading."""
    plt = plt_()
    fig, axes = plt.subplots(2, 2, figsize=(11, 6.6), sharex=True)
    cm = cmps["main"]
    for col, mem in enumerate(("feedforward", "literal")):
        for row, key in enumerate(("max_position_error", "max_heading_error")):
            ax = axes[row, col]
            if col == 0 and seeds_band is not None:
                lo, hi = seeds_band[key]
                ax.fill_between(np.arange(len(lo)), lo, hi, color="0.6", alpha=0.5, lw=0,
                                label="(9) seeds 1-5 min-max")
            for law in ("9", "22", "23"):
                lab = f"({law}) feedforward" if law == "22" else f"({law}) {mem}"
                m = cm[lab]
                ax.semilogy(m["trial"], m[key], color=COLORS[law], lw=0.8,
                            label=f"law ({law})" + (" (same in both)" if law == "22" else ""))
            ax.grid(True, which="both", alpha=0.3)
            ax.tick_params(labelsize=8)
        axes[0, col].set_title(f"memory '{mem}'", fontsize=9)
        axes[1, col].set_xlabel("trial (0 = first run)")
    axes[0, 0].set_ylabel("max position error [m]")
    axes[1, 0].set_ylabel("max heading error [rad]")
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save(fig, name)


def plot_floor(runs: dict[str, dict[str, np.ndarray]], title: str, name: str) -> None:
    plt = plt_()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    for lab, m in runs.items():
        axes[0].semilogy(m["trial"], m["max_position_error"], lw=0.8, label=lab)
        axes[1].semilogy(m["trial"], m["max_heading_error"], lw=0.8, label=lab)
    axes[0].set_ylabel("max position error [m]")
    axes[1].set_ylabel("max heading error [rad]")
    for ax in axes:
        ax.set_xlabel("trial")
        ax.grid(True, which="both", alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save(fig, name)


def plot_fig14(clean: dict[str, dict[str, np.ndarray]], cont: np.ndarray,
               noisy: dict[str, np.ndarray], name: str) -> None:
    plt = plt_()
    fig, axes = plt.subplots(2, 1, figsize=(8.5, 5.8), sharex=True)
    for row, (key, ci) in enumerate((("max_position_error", 1), ("max_heading_error", 2))):
        ax = axes[row]
        for lab, m in clean.items():
            law = lab.split()[0].strip("()")
            ls = "--" if "literal" in lab else "-"
            if lab == "(23) feedforward" or lab == "(23) literal":
                continue  # identical to law (9) without delays
            ax.semilogy(m["trial"], m[key], ls, color=COLORS[law], lw=0.9,
                        label=f"{lab}, noise-free, no delay")
        ax.semilogy(cont[:, 0], cont[:, ci], "o-", color="tab:green", ms=2.5, lw=0.9,
                    label="(9) feedforward: trials 300-324 noisy + delays, from learned memory")
        ax.semilogy(noisy["trial"], noisy[key], color="tab:orange", lw=0.7, alpha=0.8,
                    label="(9) feedforward: noisy + delays from trial 0")
        ax.axvline(299.5, color="0.5", lw=0.6, ls=":")
        ax.grid(True, which="both", alpha=0.3)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("max position error [m]")
    axes[1].set_ylabel("max heading error [rad]")
    axes[1].set_xlabel("trial (0 = first run)")
    axes[0].legend(fontsize=6.5, loc="upper right")
    fig.suptitle("paper-triangle3 (Sec. IV.B, Fig. 14 analogue), seed 1", fontsize=9)
    fig.tight_layout()
    save(fig, name)


# ------------------------------------------------------------------------------ main

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, default=Path("/tmp/formation-ilc-reproduction"))
    ap.add_argument("--seeds", default="1,2,3,4,5")
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    R = a.runs
    R.mkdir(parents=True, exist_ok=True)
    FIG.mkdir(parents=True, exist_ok=True)
    num: dict = {"seeds": seeds}
    git = ["git", "-C", str(ROOT)]
    num["commit"] = subprocess.run([*git, "rev-parse", "--short", "HEAD"], text=True,
                                   capture_output=True).stdout.strip()
    num["core_modified"] = subprocess.run(
        [*git, "status", "--short", "--", "formation_ilc"], text=True,
        capture_output=True).stdout.splitlines()

    # --- every CLI run, independent of each other: run them in parallel
    ms = str(seeds[0])
    jobs: list[tuple[list[str], Path | None]] = []
    checks = [("hexagon6", "paper-hexagon6", law, mem) for law in (9, 22, 23)
              for mem in ("feedforward", "literal") if not (law == 22 and mem == "literal")]
    checks += [("triangle3", "paper-triangle3", 9, mem) for mem in ("feedforward", "literal")]
    for tag, name, law, mem in checks:
        jobs.append((["check", name, "--law", str(law), "--memory", mem],
                     R / f"check-{tag}-{law}-{mem}.txt"))
    # the paper's effective gain (paper-notes 11): dT left out of B = gain 0.8 with B as printed
    src = (ROOT / "formation_ilc" / "config" / "scenarios" / "paper-hexagon6.yaml").read_text()
    g08 = re.sub(r"(?m)^  gain: 0\.08 .*$", "  gain: 0.8", src)
    g08 = re.sub(r"(?m)^  gain_prime: 0\.08 .*$", "  gain_prime: 0.8", g08)
    g08 = g08.replace("name: paper-hexagon6", "name: paper-hexagon6-gain0.8")
    assert g08.count("0.8\n") >= 2, "gain substitution failed"
    (R / "hexagon6-gain08.yaml").write_text(g08)
    nod = re.sub(r"(?m)^  model: paper .*$", "  model: none", src)
    assert "model: none" in nod, "delay substitution failed"
    (R / "hexagon6-nodelay.yaml").write_text(nod.replace("name: paper-hexagon6",
                                                         "name: paper-hexagon6-nodelay"))
    extra_checks = {"gain08 (9) feedforward": ["check", str(R / "hexagon6-gain08.yaml")],
                    "nodelay (9) literal": ["check", str(R / "hexagon6-nodelay.yaml"),
                                            "--memory", "literal"]}
    for key, args in extra_checks.items():
        jobs.append((args, R / f"check-{key.split()[0]}.txt"))
    # Sec. IV.A: laws 9 / 22 / 23 in both memory readings, 2000 trials, several seeds
    for s in seeds:
        jobs.append((["compare", "paper-hexagon6", "--trials", "2000", "--seed", str(s),
                      "--out", str(R / f"hex-compare-seed{s}")], None))
    extras = {"delay-only": ["--no-noise"], "clean": ["--no-noise", "--no-delay"]}
    for extra, flags in extras.items():
        jobs.append((["compare", "paper-hexagon6", "--trials", "2000", "--seed", ms,
                      "--out", str(R / f"hex-compare-{extra}"), *flags], None))
    jobs.append((["compare", str(R / "hexagon6-gain08.yaml"), "--trials", "2000", "--seed", ms,
                  "--out", str(R / "hex-compare-gain08")], None))
    # law (9) feed-forward with the trajectories of the paper's iterations (both captions)
    keep = "0,99,199,299,799,999,1999"
    hexd, hexlit = R / "hex-law9-ff", R / "hex-law9-literal"
    jobs.append((["simulate", "paper-hexagon6", "--trials", "2000", "--seed", ms,
                  "--keep", keep, "--out", str(hexd), "--no-plots"], None))
    jobs.append((["simulate", "paper-hexagon6", "--trials", "2000", "--seed", ms,
                  "--memory", "literal", "--keep", "0,99,199,1999", "--out", str(hexlit),
                  "--no-plots"], None))
    floor_runs = {"noise + delays (paper)": ("full", []), "noise only": ("noise", ["--no-delay"]),
                  "delays only": ("delays", ["--no-noise"]),
                  "neither": ("neither", ["--no-noise", "--no-delay"])}
    for _lab, (tag, flags) in floor_runs.items():
        jobs.append((["simulate", "paper-hexagon6", "--trials", "2000", "--seed", ms,
                      "--out", str(R / f"hex-law9-ff-{tag}"), "--no-plots", *flags], None))
    # Sec. IV.B: 3 robots, 300 noise-free trials, then the noisy phase
    tri_keep = "0,2,9,24,99,299"
    tric, trin = R / "tri-clean", R / "tri-noisy"
    jobs.append((["simulate", "paper-triangle3", "--no-noise", "--no-delay", "--seed", ms,
                  "--keep", tri_keep, "--out", str(tric), "--no-plots"], None))
    # noise-free and delay-free, a run draws nothing random: seed 2 must repeat seed 1 exactly
    jobs.append((["simulate", "paper-triangle3", "--no-noise", "--no-delay", "--seed", "2",
                  "--out", str(R / "tri-clean-seed2"), "--no-plots"], None))
    jobs.append((["simulate", "paper-triangle3", "--seed", ms, "--keep", tri_keep,
                  "--out", str(trin), "--no-plots"], None))
    tcmp, tcmpn = R / "tri-compare-clean", R / "tri-compare-noisy"
    jobs.append((["compare", "paper-triangle3", "--no-noise", "--no-delay", "--seed", ms,
                  "--out", str(tcmp)], None))
    jobs.append((["compare", "paper-triangle3", "--seed", ms, "--out", str(tcmpn)], None))
    for s in seeds[1:]:
        jobs.append((["simulate", "paper-triangle3", "--seed", str(s),
                      "--out", str(R / f"tri-noisy-seed{s}"), "--no-plots"], None))
    run_all(jobs)

    num["check"] = {f"{tag} ({law}) {mem}": parse_check(
        (R / f"check-{tag}-{law}-{mem}.txt").read_text()) for tag, _n, law, mem in checks}
    for key in extra_checks:
        num["check"][key] = parse_check((R / f"check-{key.split()[0]}.txt").read_text())
    cmps: dict = {s: compare_metrics(R / f"hex-compare-seed{s}") for s in seeds}
    num["hex_compare"] = {str(s): {lab: stats(m, 100) for lab, m in c.items()}
                          for s, c in cmps.items()}
    main_seed = seeds[0]
    for extra in (*extras, "gain08"):
        cmps[extra] = compare_metrics(R / f"hex-compare-{extra}")
        num[f"hex_compare_{extra}"] = {lab: stats(m, 100) for lab, m in cmps[extra].items()}
    floor = {lab: read_metrics(R / f"hex-law9-ff-{tag}" / "metrics.csv")
             for lab, (tag, _f) in floor_runs.items()}
    num["hex_floor"] = {lab: stats(m, 100) for lab, m in floor.items()}
    tri_clean_cmp = compare_metrics(tcmp)
    num["tri_compare_clean"] = {lab: stats(m, 25) for lab, m in tri_clean_cmp.items()}
    num["tri_compare_noisy"] = {lab: stats(m, 25) for lab, m in
                                compare_metrics(tcmpn).items()}
    a1 = read_metrics(tric / "metrics.csv")["max_position_error"]
    a2 = read_metrics(R / "tri-clean-seed2" / "metrics.csv")["max_position_error"]
    num["tri_clean_seed_independent"] = bool(np.array_equal(a1, a2))
    tri_noisy = {s: R / ("tri-noisy" if s == main_seed else f"tri-noisy-seed{s}")
                 for s in seeds}
    num["tri_noisy_seeds"] = {str(s): stats(read_metrics(d / "metrics.csv"), 25)
                              for s, d in tri_noisy.items()}

    # sim-to-real analogue (library call; the CLI's --init-memory does the same)
    print("$ python: simulate(paper-triangle3 noisy + delays, trials 300..324, "
          "initial_memory = memory after 300 noise-free trials)")
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.model.simulate import simulate

    base = load_scenario("paper-triangle3").with_options(seed=main_seed)
    from formation_ilc.store.memoryfile import load_memory

    mem = load_memory(tric / "memory.npz", base)
    cont = simulate(base, trials=25, initial_memory=mem, first_trial=300,
                    keep=[300, 302, 309, 324])
    num["tri_continuation"] = {
        "trial": cont.metrics[:, 0].astype(int).tolist(),
        "max_position_error": cont.column("max_position_error").tolist(),
        "max_heading_error": cont.column("max_heading_error").tolist(),
    }
    cont_seeds = {}
    for s in seeds:
        c = simulate(base.with_options(seed=s), trials=25, initial_memory=mem, first_trial=300)
        p = c.column("max_position_error")
        cont_seeds[s] = {"first": float(p[0]), "last": float(p[-1]),
                         "median_last10": float(np.median(p[-10:]))}
    num["tri_continuation_seeds"] = cont_seeds


    hx = load_scenario("paper-hexagon6")
    tr = load_scenario("paper-triangle3")
    num["desired"] = {}
    for sc in (hx, tr):
        d = sc.desired
        steps = np.diff(d.eta[:, :, :2], axis=1)
        num["desired"][sc.name] = {
            "path_length": np.hypot(steps[..., 0], steps[..., 1]).sum(1).round(2).tolist(),
            "min_v": float(d.u[..., 0].min()), "max_v": float(d.u[..., 0].max()),
            "max_abs_w": float(np.abs(d.u[..., 1]).max()),
            "leader_turn": float(d.reference[-1, 2] - d.reference[0, 2]),
        }
    # in trial 1999 of the main run: where the largest true error is, along / across path
    z = np.load(hexd / "trajectories.npz")
    e = z["eta_d"][:, 1:, :2] - z["xi_1999"][:, 1:, :2]
    th = z["eta_d"][:, 1:, 2]
    along = e[..., 0] * np.cos(th) + e[..., 1] * np.sin(th)
    across = -e[..., 0] * np.sin(th) + e[..., 1] * np.cos(th)
    p = np.hypot(e[..., 0], e[..., 1])
    i, t = np.unravel_index(int(p.argmax()), p.shape)
    dh = np.abs((z["eta_d"][:, 1:, 2] - z["xi_1999"][:, 1:, 2] + np.pi) % (2 * np.pi) - np.pi)
    num["hex_trial1999_error_split"] = {
        "max_true_pos": float(p.max()), "robot": int(i) + 1, "t": int(t) + 1,
        "along_at_max": float(along[i, t]), "across_at_max": float(across[i, t]),
        "max_abs_along": float(np.abs(along).max()),
        "max_abs_across": float(np.abs(across).max()),
        "true_heading_mean": float(dh.mean()), "true_heading_max": float(dh.max()),
    }
    (FIG / "numbers.json").write_text(json.dumps(num, indent=1) + "\n")

    # --- figures
    print("figures:")
    plot_desired(hx, "paper-hexagon6: desired formation (Fig. 4); hexagon fixed in the "
                     "world frame, radius s(t)", "fig04_hexagon_desired.png")
    plot_desired(tr, "paper-triangle3: desired formation (Fig. 12); triangle in the "
                     "leader's body frame", "fig12_triangle_desired.png", n_snap=8)
    z = np.load(hexd / "trajectories.npz")
    runs = {f"iteration {k + 1} (trial {k})": z[f"eta_{k}"] for k in map(int, keep.split(","))}
    xis = {f"iteration {k + 1} (trial {k})": z[f"xi_{k}"] for k in map(int, keep.split(","))}
    plot_trials(z["eta_d"], runs, f"paper-hexagon6, law (9), memory feedforward, noise + "
                f"delays, seed {main_seed}: measured paths (solid) vs desired (dashed)",
                "fig06_hexagon_trials.png", cols=4, xi_runs=xis)
    zl = np.load(hexlit / "trajectories.npz")
    runs = {f"iteration {k + 1} (trial {k})": zl[f"eta_{k}"] for k in (0, 99, 199, 1999)}
    plot_trials(zl["eta_d"], runs, f"paper-hexagon6, law (9), memory LITERAL, seed "
                f"{main_seed}: measured paths", "fig06b_hexagon_literal_trials.png", cols=4,
                err_panel=False)
    band = None
    if len(seeds) > 1:
        band = {}
        for key in ("max_position_error", "max_heading_error"):
            arr = np.array([cmps[s]["(9) feedforward"][key] for s in seeds])
            band[key] = (arr.min(0), arr.max(0))
    plot_laws({"main": cmps[main_seed]}, band,
              f"paper-hexagon6 (Fig. 7): laws (9) black, (22) blue, (23) red; 2000 trials, "
              f"noise + delays, seed {main_seed}", "fig07_hexagon_laws.png")
    plot_floor(floor, f"paper-hexagon6, law (9) feedforward, seed {main_seed}: what sets "
               "the error floor", "fig07b_hexagon_floor.png")
    plot_laws({"main": cmps["gain08"]}, None,
              f"paper-hexagon6 with gain 0.8 (dT left out of B, the paper's 0.9783), noise + "
              f"delays, seed {main_seed}", "fig07d_hexagon_laws_gain08.png")
    plot_laws({"main": cmps["clean"]}, None,
              f"paper-hexagon6: laws (9), (22), (23) WITHOUT noise and delays, seed "
              f"{main_seed}", "fig07c_hexagon_laws_clean.png")
    plot_fig14(tri_clean_cmp, cont.metrics, read_metrics(trin / "metrics.csv"),
               "fig14_triangle_errors.png")
    zc = np.load(tric / "trajectories.npz")
    runs = {f"sim trial {k}": zc[f"eta_{k}"] for k in (0, 24, 299)}
    runs.update({f"noisy trial {k} = 'real' {k - 299}": cont.records[k].eta
                 for k in (300, 302, 309, 324)})
    xis = {f"sim trial {k}": zc[f"xi_{k}"] for k in (0, 24, 299)}
    xis.update({f"noisy {k}": cont.records[k].xi for k in (300, 302, 309, 324)})
    plot_trials(zc["eta_d"], runs, "paper-triangle3 (Fig. 15 analogue), law (9) "
                "feedforward, seed 1: noise-free trials 0/24/299, then noisy + delayed "
                "trials 300/302/309/324 from the learned memory", "fig15_triangle_trials.png",
                cols=4, xi_runs=xis)
    return 0


if __name__ == "__main__":
    sys.exit(main())
