#!/usr/bin/env python3
"""The paper's sim-to-real workflow on the physics plant (docs/reproduction.md, "Sim-to-real
on physics").

    .venv/bin/python scripts/physics_study.py [--trials 30] [--kin-trials 300] [--only p3dx]

For each team: learn ``--kin-trials`` noise-free trials in the batch simulator with the
exact-arc plant model (the kinematic model that drives arcs, with arc headings), carry the
memory to the PyBullet plant, and run ``--trials`` trials there from it (warm) and from
zero (cold), learning from ground truth. Prints and writes (docs/figures/physics.json,
docs/figures/physics_sim_to_real.png): the first-trial error cold and warm, the trials the
physics runs need to come within 10 % of the kinematic floor, the physics floor (mean of the
last 10 trials), contacts and the largest tilt. Teams: paper-triangle3 on the P3-DX-size
robot; paper-triangle3 with its offsets doubled on the Husky (its 0.99 m body at the
paper's spacing would overlap from the start). The memory-chord run is the same warm start
with the chord headings learned on the Euler model, for comparison. A few minutes a team
(2 cores).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from formation_ilc.config.scenario import Scenario, load_scenario, scenario_from_text  # noqa: E402
from formation_ilc.model.physics import MODELS  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402

FIG = ROOT / "docs" / "figures"


def husky_triangle() -> Scenario:
    text = load_scenario("paper-triangle3").text
    text = (text.replace("1: {x: 1.0, y: 0.0, scale: D1}", "1: {x: 2.0, y: 0.0, scale: D1}")
            .replace("2: {x: 0.0, y: 1.0, scale: D2}", "2: {x: 0.0, y: 2.0, scale: D2}")
            .replace("3: {x: 0.0, y: -1.0, scale: D2}", "3: {x: 0.0, y: -2.0, scale: D2}")
            .replace("name: paper-triangle3", "name: husky-triangle3"))
    return scenario_from_text(text, "husky-triangle3 (paper-triangle3, offsets x 2)")


def first_within(x: np.ndarray, level: float) -> int | None:
    hit = np.flatnonzero(x <= level)
    return int(hit[0]) if hit.size else None


def team(name: str, sc: Scenario, model: str, trials: int, kin_trials: int) -> dict:
    quiet = sc.with_options(noise=False, delay=False)
    t0 = time.perf_counter()
    kin = simulate(quiet.with_options(trials=kin_trials), plant="arc")
    kin_err = kin.column("max_position_error")
    kin_floor = float(kin_err[-10:].mean())
    print(f"{name}: kinematic (arc) {kin_trials} trials: first {kin_err[0]:.3f} m, floor "
          f"{kin_floor:.3f} m [{time.perf_counter() - t0:.0f} s]", flush=True)
    out: dict = {"scenario": sc.name, "model": model, "kinematic_trials": kin_trials,
                 "kinematic_first": float(kin_err[0]), "kinematic_floor": kin_floor,
                 "kinematic_curve": kin_err[:trials].tolist()}
    for run, memory in (("warm", kin.memory), ("cold", None)):
        t0 = time.perf_counter()
        res = run_physics(quiet, MODELS[model], trials, memory=memory,
                          progress=lambda k, row, run=run: print(f"  {name} {run} trial {k}: "
                                                        f"{row[1]:.3f} m", flush=True))
        err = res.column("max_position_error")
        touched = [k for k, c in enumerate(res.contacts) if c]
        out[run] = {"first": float(err[0]), "floor": float(err[-10:].mean()),
                    "trials_to_kinematic_floor": first_within(err, 1.1 * kin_floor),
                    "curve": err.tolist(), "trials_with_contact": touched,
                    "tilt_max_deg": float(np.degrees(max(res.tilt))),
                    "least_clearance": float(min(c.value for c in res.clearance)),
                    "samples_per_s": res.samples / res.seconds}
        print(f"{name} {run}: first {err[0]:.3f} m, floor {out[run]['floor']:.3f} m, "
              f"within 10 % of the kinematic floor at trial "
              f"{out[run]['trials_to_kinematic_floor']}, contact in trials {touched}, "
              f"{res.samples / res.seconds:.1f} samples/s "
              f"[{time.perf_counter() - t0:.0f} s]", flush=True)
    return out


def noisy_floor(name: str, sc: Scenario, model: str, trials: int, kin_trials: int) -> dict:
    """The floor with the scenario's uncertainty (initial shifts and output noise; no delay:
    links are direct in lockstep): batch simulator (arc model, with its input disturbance
    too) against physics warm-started from the noise-free kinematic memory."""
    kin = simulate(sc.with_options(noise=False, delay=False, trials=kin_trials), plant="arc")
    noisy = sc.with_options(delay=False)
    batch = simulate(noisy.with_options(trials=kin_trials), plant="arc")
    b = batch.column("max_position_error")
    res = run_physics(noisy, MODELS[model], trials, memory=kin.memory,
                      progress=lambda k, row: print(f"  {name} noisy trial {k}: {row[1]:.3f} m",
                                                    flush=True))
    err = res.column("max_position_error")
    out = {"batch_floor": float(b[-50:].mean()), "physics_first": float(err[0]),
           "physics_floor": float(err[-10:].mean()), "curve": err.tolist(),
           "trials_with_contact": [k for k, c in enumerate(res.contacts) if c]}
    print(f"{name} noisy: batch (arc) floor {out['batch_floor']:.3f} m, physics floor "
          f"{out['physics_floor']:.3f} m ({out['physics_floor'] / out['batch_floor']:.2f} x)",
          flush=True)
    return out


def plot(results: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4), squeeze=False)
    for ax, (name, r) in zip(axes[0], results.items(), strict=True):
        if r.get("kinematic_curve"):
            ax.semilogy(r["kinematic_curve"], label="kinematic (arc model), from zero",
                        color="k")
        if "cold" in r:
            ax.semilogy(r["cold"]["curve"], label="physics, cold (from zero)", color="tab:red")
        ax.semilogy(r["warm"]["curve"], label=f"physics, warm ({r['kinematic_trials']} "
                                              f"kinematic trials)", color="tab:blue")
        ax.axhline(r["kinematic_floor"], color="k", ls=":", label="kinematic floor")
        for run, color in (("cold", "tab:red"), ("warm", "tab:blue")):
            for k in r.get(run, {}).get("trials_with_contact", []):
                ax.axvline(k, color=color, alpha=0.12)
        ax.set_title(f"{r['scenario']} on {name}")
        ax.set_xlabel("trial")
        ax.set_ylabel("max position error [m]")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--kin-trials", type=int, default=300)
    ap.add_argument("--only", choices=("p3dx", "husky"))
    ap.add_argument("--out", type=Path, default=FIG / "physics.json")
    ap.add_argument("--noisy", action="store_true",
                    help="only the floor with the scenario's noise (physics.noisy.json)")
    ap.add_argument("--plot", nargs="+", type=Path, metavar="JSON",
                    help="only draw the figure from earlier results")
    args = ap.parse_args()
    teams = {"p3dx": ("paper-triangle3", load_scenario("paper-triangle3")),
             "husky": ("husky-triangle3", husky_triangle())}
    if args.plot:
        results = {}
        for path in args.plot:
            results.update(json.loads(path.read_text()))
        plot(results, FIG / "physics_sim_to_real.png")
        return 0
    if args.noisy:
        noisy = {m: noisy_floor(m, sc, m, args.trials, args.kin_trials)
                 for m, (_, sc) in teams.items() if args.only in (None, m)}
        args.out.write_text(json.dumps(noisy, indent=1) + "\n")
        return 0
    results = {}
    for model, (_, sc) in teams.items():
        if args.only in (None, model):
            results[model] = team(model, sc, model, args.trials, args.kin_trials)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    plot(results, args.out.with_name("physics_sim_to_real.png"))
    print(f"wrote {args.out} and {args.out.with_name('physics_sim_to_real.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
