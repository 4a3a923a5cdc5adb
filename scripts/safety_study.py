#!/usr/bin/env python3
"""Cold starts on bodies through the safety filter (docs/safety.md).

    .venv/bin/python scripts/safety_study.py [--trials 50] [--only triangle]

Each team learns from u = 0, without noise or delay, on the physics plant in one process
(``studies.physics.run_physics``: the law, the filter and the PyBullet world, as the stack
runs them in lockstep), with the filter and without it (robots then collide), beside the
batch simulator's prediction through the same filter (``simulate(safety=...)``, the exact-
arc model) and the kinematic run without it:

* triangle: paper-triangle3 on P3-DX-size robots (the paper's experiment);
* hexagon: docs/examples/hexagon6-p3dx.yaml (paper-hexagon6 made to fit a P3-DX: a third
  of its speed, eased in from rest, twice its width, tuned gains);
* husky: paper-triangle3 with its offsets doubled on the skid-steer Husky; husky-imu: the
  same on a Husky whose base closes velocity loops (docs/physics.md, "Skid steer").

Writes docs/figures/safety.json (every curve) and docs/figures/safety_*.png (error per
trial with and without the filter; the commands the filter changed per trial, physics
against the batch prediction). A few minutes a team on 2 cores.
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
sys.path.insert(0, str(ROOT / "scripts"))

from physics_study import husky_triangle  # noqa: E402

from formation_ilc.config.safety import (  # noqa: E402
    SafetySettings,
    default_learning,
    default_margin,
)
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.model.footprint import trial_clearance  # noqa: E402
from formation_ilc.model.physics import MODELS  # noqa: E402
from formation_ilc.model.safety import spec_of  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402

FIG = ROOT / "docs" / "figures"
TEAMS = {
    "triangle": (lambda: load_scenario("paper-triangle3"), "p3dx"),
    "hexagon": (lambda: load_scenario(str(ROOT / "docs" / "examples" / "hexagon6-p3dx.yaml")),
                "p3dx"),
    "husky": (husky_triangle, "husky"),
    "husky-imu": (husky_triangle, "husky-imu"),
}


def physics(sc, body: str, trials: int, spec, label: str) -> dict:
    t0 = time.perf_counter()
    res = run_physics(sc, MODELS[body], trials, safety=spec,
                      progress=lambda k, row: print(f"  {label} trial {k}: true "
                                                    f"{row[3]:.3f} m, filtered {int(row[7])}, "
                                                    f"contacts {int(row[8])}", flush=True))
    print(f"  {label}: {time.perf_counter() - t0:.0f} s", flush=True)
    return {"true": res.column("true_max_position_error").tolist(),
            "filtered": res.filtered, "contacts": [len(c) for c in res.contacts],
            "trials_with_contact": [k for k, c in enumerate(res.contacts) if c],
            "tilt_max_deg": float(np.degrees(max(res.tilt))),
            "least_clearance": [c.value for c in res.clearance]}


def batch(sc, body: str, trials: int, spec) -> dict:
    fp = MODELS[body].footprint
    clear: list[float] = []
    res = simulate(sc.with_options(trials=trials), plant="arc", safety=spec,
                   on_trial_data=lambda k, xi, *r: clear.append(trial_clearance(k, xi,
                                                                                fp).value))
    return {"error": res.column("max_position_error").tolist(),
            "filtered": res.column("filter_active").astype(int).tolist(),
            "overlapping_trials": int(sum(c < 0 for c in clear)),
            "least_clearance": float(min(clear))}


def team(name: str, trials: int) -> dict:
    make, body = TEAMS[name]
    sc = make().with_options(noise=False, delay=False)
    m = MODELS[body]
    settings = SafetySettings(body, m.limits, margin=default_margin(body),
                              learning=default_learning(body))
    spec = spec_of(settings, sc.dt)
    print(f"{name}: {sc.name} on {body}, {trials} trials, learning {settings.learning}",
          flush=True)
    out = {"scenario": sc.name, "body": body, "learning": settings.learning,
           "limits": settings.to_json()["limits"], "trials": trials,
           "batch_filtered": batch(sc, body, trials, spec),
           "batch_free": batch(sc, body, trials, None)}
    out["physics_filtered"] = physics(sc, body, trials, spec, f"{name} filtered")
    out["physics_free"] = physics(sc, body, trials, None, f"{name} free")
    return out


def plot(name: str, d: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = np.arange(d["trials"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    a.semilogy(k, d["physics_filtered"]["true"], label="physics, through the filter")
    a.semilogy(k, d["physics_free"]["true"], label="physics, no filter (robots collide)")
    a.semilogy(k, d["batch_filtered"]["error"], "--", label="batch prediction, filter")
    a.semilogy(k, d["batch_free"]["error"], ":", label="kinematic, no filter (no bodies)")
    hit = d["physics_free"]["trials_with_contact"]
    if hit:
        a.plot(hit, [d["physics_free"]["true"][i] for i in hit], "x", color="C1",
               label="trial with contact")
    a.set_xlabel("trial")
    a.set_ylabel("max position error [m] (true)")
    a.set_title(f"{d['scenario']} on {d['body']}, cold start")
    a.legend(fontsize=8)
    b.plot(k, d["physics_filtered"]["filtered"], label="physics")
    b.plot(k, d["batch_filtered"]["filtered"], "--", label="batch prediction")
    b.set_xlabel("trial")
    b.set_ylabel("commands the filter changed")
    b.set_title(f"filter activity (learning: {d['learning']})")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(FIG / f"safety_{name}.png", dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--only", nargs="+", choices=tuple(TEAMS), default=list(TEAMS))
    args = ap.parse_args()
    path = FIG / "safety.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for name in args.only:
        results[name] = team(name, args.trials)
        path.write_text(json.dumps(results, indent=1) + "\n")
        plot(name, results[name])
        d = results[name]
        pf, pb = d["physics_filtered"], d["batch_filtered"]
        last = pf["true"][-1]
        agree = [abs(a - b) / max(b, 1) for a, b in zip(pf["filtered"], pb["filtered"],
                                                          strict=True)]
        print(f"{name}: physics through the filter: contacts {sum(pf['contacts'])}, tilt "
              f"{pf['tilt_max_deg']:.2f} deg, true error trial {args.trials - 1} "
              f"{last:.3f} m; without: contact in {len(d['physics_free']['trials_with_contact'])}"
              f" trials; filter counts physics vs batch: total {sum(pf['filtered'])} vs "
              f"{sum(pb['filtered'])}, median per-trial difference {np.median(agree):.0%}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
