#!/usr/bin/env python3
"""The safety filter on formations nobody tuned (docs/safety.md, "Judged on families").

    .venv/bin/python scripts/families_study.py [--seeds 10] [--noisy-seeds 4] [--trials 100]
                                              [--first-seed 0] [--no-write]
    .venv/bin/python scripts/families_study.py --physics crossing-0 swapping-5 [--trials 40]
    .venv/bin/python scripts/families_study.py --table 3 --kinds orbit tusi ... \
                                              [--motion both] [--at 10 30 60] [--poses noisy]

For each family of ``studies.families`` (``--kinds``; default crossing, following, swapping)
and each seed, the member that fits a Pioneer 3-DX (``check --base p3dx`` passes) learns
from u = 0 in the batch simulator (exact-arc kinematics, the paper's delays) twice: through
the safety filter (the default learning reading, ``damped``) and without it. It prints one
row per member: the error at the last trial of both and their ratio, footprint overlaps
(trials), the least clearance, and the commands the filter changed in the first trial and on
average over the last ten. ``--noisy-seeds`` members more per family carry the paper's noise
(drawn half as wide again). Writes docs/figures/families.json (every curve) and families.png
(error and filter changes per trial, each family's members; only with the default ``--motion
poses``). About 75 s on 2 cores. ``--first-seed`` starts the seeds elsewhere: members no
choice of the filter's was measured on (a held-out check of a change tuned on the default
seeds; it writes nothing unless asked).

``--table MEMBERS``: MEMBERS members of each of ``--kinds``, exact and noisy, cold through
the filter (with ``--motion``: the other robots' motion estimated from their poses, or told
as commands; ``both``) and without it, to trial max(``--at``): a line per member, then a
markdown table per motion of the median errors through / without the filter at ``--at``,
the median of the members' ratios, and the filter's changes over the first and last 10
trials (docs/safety.md's table of every kind).

``--physics KIND-SEED ...``: those members cold on the physics plant instead (PyBullet, one
process, lockstep, no delay, exact poses, P3-DX bodies, the filter with ``damped``), beside
the kinematic run without the filter and the same bodies without the filter: one row each
with contacts, the largest tilt, the least clearance of the bodies, the true error at the
first and last trial, the two runs without the filter at the last (the bodies' with their
contacts) and the filter's changes in trial 1 and the last. Two to five minutes a member.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from formation_ilc.model.footprint import footprint_of, trial_clearance  # noqa: E402
from formation_ilc.model.safety import body_spec  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.studies.families import KINDS, family_scenario  # noqa: E402

FIG = ROOT / "docs" / "figures"
FP = footprint_of("p3dx")


def member(kind: str, seed: int, noise: bool, trials: int, motion: str = "poses") -> dict:
    sc = family_scenario(kind, seed, noise=noise, trials=trials)
    spec = body_spec("p3dx", sc.dt, sc.uncertainty, motion=motion)
    clear: list[float] = []
    safe = simulate(sc, trials, plant="arc", safety=spec, on_trial_data=lambda k, xi, *r:
                    clear.append(trial_clearance(k, xi, FP).value))
    free_clear: list[float] = []
    free = simulate(sc, trials, plant="arc", on_trial_data=lambda k, xi, *r:
                    free_clear.append(trial_clearance(k, xi, FP).value))
    return {"kind": kind, "seed": seed, "noise": noise, "robots": sc.n,
            "safe": safe.column("max_position_error").tolist(),
            "free": free.column("max_position_error").tolist(),
            "changed": safe.column("filter_active").tolist(),
            "overlaps": int(sum(c < 0 for c in clear)), "least": float(min(clear)),
            "free_overlaps": int(sum(c < 0 for c in free_clear))}


def table_member(kind: str, seed: int, noise: bool, trials: int,
                 motions: list[str]) -> dict:
    """One member of ``--table``: the error per trial without the filter and through it
    for each of ``motions``, the filter's changes per trial and the trials whose
    footprints overlapped, each motion's."""
    sc = family_scenario(kind, seed, noise=noise, trials=trials)
    row: dict = {"kind": kind, "seed": seed, "noise": noise, "robots": sc.n,
                 "free": simulate(sc, trials, plant="arc").column("max_position_error").tolist()}
    for motion in motions:
        spec = body_spec("p3dx", sc.dt, sc.uncertainty, motion=motion)
        clear: list[float] = []
        res = simulate(sc, trials, plant="arc", safety=spec,
                       on_trial_data=lambda k, xi, *r, into=clear:
                       into.append(trial_clearance(k, xi, FP).value))
        row[motion] = {"safe": res.column("max_position_error").tolist(),
                       "changed": res.column("filter_active").tolist(),
                       "overlaps": int(sum(c < 0 for c in clear))}
    return row


def table(kinds: list[str], members: int, first: int, at: list[int],
          motions: list[str], noises: tuple[bool, ...] = (False, True)) -> list[dict]:
    """``--table``: ``members`` members of each kind, exact and noisy, through the filter
    with each of ``motions`` and without it; one line per member, then a markdown table
    per motion: the median error through the filter / without it at the trials ``at``
    (0-based; the median of the members' ratios in brackets) and the median of the
    filter's changes a trial over the first and the last 10 trials."""
    trials = max(at) + 1
    rows = []
    for kind in kinds:
        for noise in noises:
            for seed in range(first, first + members):
                try:
                    r = table_member(kind, seed, noise, trials, motions)
                except ValueError as exc:  # no draw fits
                    print(f"{kind}-{seed}{' noisy' if noise else ''}: {exc}", flush=True)
                    continue
                rows.append(r)
                cells = "  ".join(
                    f"{m}: " + " ".join(f"{r[m]['safe'][t]:.3f}/{r['free'][t]:.3f}" for t in at)
                    + f" changed {np.mean(r[m]['changed'][:10]):.0f}/"
                      f"{np.mean(r[m]['changed'][-10:]):.0f} overlaps {r[m]['overlaps']}"
                    for m in motions)
                print(f"{kind + '-' + str(seed) + (' noisy' if noise else ''):<16} "
                      f"n={r['robots']:<2} {cells}", flush=True)
    for m in motions:
        print(f"\nmotion={m}: median error through the filter / without it [m] "
              f"(median ratio)\n")
        print("| kind | poses | members | robots | " +
              " | ".join(f"trial {t}" for t in at) +
              " | changed a trial, first 10 / last 10 | overlaps |")
        print("| --- | --- | ---: | ---: | " + " | ".join("---:" for _ in at) + " | ---: | ---: |")
        for kind in kinds:
            for noise in (False, True):
                part = [r for r in rows if r["kind"] == kind and r["noise"] == noise]
                if not part:
                    continue
                out: list[str] = []
                for t in at:
                    safe = np.median([r[m]["safe"][t] for r in part])
                    free = np.median([r["free"][t] for r in part])
                    ratio = np.median([r[m]["safe"][t] / r["free"][t] for r in part])
                    out.append(f"{safe:.3f} / {free:.3f} ({ratio:.2f}x)")
                first10 = np.median([np.mean(r[m]["changed"][:10]) for r in part])
                last10 = np.median([np.mean(r[m]["changed"][-10:]) for r in part])
                sizes = sorted({r["robots"] for r in part})
                print(f"| {kind} | {'noisy' if noise else 'exact'} | {len(part)} | "
                      f"{sizes[0]}-{sizes[-1]} | " + " | ".join(out) +
                      f" | {first10:.0f} / {last10:.0f} | "
                      f"{sum(r[m]['overlaps'] for r in part)} |")
    return rows


def member_name(text: str) -> tuple[str, int]:
    """``--physics``'s KIND-SEED as (kind, seed); argparse's one-line error (exit 2) else."""
    kind, _, seed = text.rpartition("-")
    if kind not in KINDS or not seed.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r} is not KIND-SEED with KIND one of "
                                         f"{', '.join(KINDS)} and SEED a whole number")
    return kind, int(seed)


def on_physics(kind: str, seed: int, trials: int) -> str:
    """One row of ``--physics``: member ``kind``-``seed`` cold on the physics plant."""
    from formation_ilc.model.physics import MODELS
    from formation_ilc.studies.physics import run_physics

    name = f"{kind}-{seed}"
    sc = family_scenario(kind, seed, trials=trials).with_options(delay=False)
    spec = body_spec("p3dx", sc.dt, sc.uncertainty)
    res = run_physics(sc, MODELS["p3dx"], trials, safety=spec)
    true = res.column("true_max_position_error")
    free = simulate(sc, trials, plant="arc").column("max_position_error")
    # the same bodies without the filter: what the plant itself lets the learning reach
    bare = run_physics(sc, MODELS["p3dx"], trials, safety=None)
    bare_true = bare.column("true_max_position_error")
    contacts = sum(len(c) for c in res.contacts)
    bare_contacts = sum(len(c) for c in bare.contacts)
    return (f"{name:<14} {contacts:>8} {np.degrees(max(res.tilt)):>7.2f} deg "
            f"{min(c.value for c in res.clearance):>7.3f} m {true[0]:>7.3f} / {true[-1]:.3f} m "
            f"{free[-1]:>9.3f} m {bare_true[-1]:>9.3f} m ({bare_contacts} contacts) "
            f"{res.filtered[min(1, trials - 1)]:>8} / {res.filtered[-1]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--noisy-seeds", type=int, default=4)
    ap.add_argument("--trials", type=int, default=None,
                    help="cold trials a member (default 100; 40 with --physics)")
    ap.add_argument("--first-seed", type=int, default=0,
                    help="the first seed of each family (default 0, the documented members)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS[:3]),
                    help="the families studied (default: crossing following swapping, "
                         "the documented study's)")
    ap.add_argument("--motion", choices=("poses", "commands", "both"), default="poses",
                    help="the filter's estimate of the other robots' motion "
                         "(body_spec(motion=...); --table takes both)")
    ap.add_argument("--table", type=int, metavar="MEMBERS",
                    help="MEMBERS members of each kind, exact and noisy, judged at --at")
    ap.add_argument("--at", type=int, nargs="+", default=[10, 30, 60],
                    help="--table's trials (0-based; default 10 30 60)")
    ap.add_argument("--json", type=Path, help="--table: write every member's curves here")
    ap.add_argument("--poses", choices=("exact", "noisy", "both"), default="both",
                    help="--table: members with exact poses, with the paper's noise, or both")
    ap.add_argument("--physics", nargs="+", metavar="KIND-SEED", type=member_name,
                    help="run these members on the physics plant instead (e.g. crossing-0; "
                         "--trials then defaults to 40)")
    args = ap.parse_args()
    if args.trials is not None and args.trials < 1:
        ap.error(f"argument --trials: {args.trials} is not a positive number of trials")
    if args.physics:
        trials = args.trials or 40
        print(f"{'member':<14} {'contacts':>8} {'tilt':>11} {'least':>9} "
              f"{'true error, first / last':>24} {'free, last':>11} "
              f"{'bodies without the filter, last':>32} {'changed, trial 1 / last':>24}")
        for kind, seed in args.physics:
            print(on_physics(kind, seed, trials), flush=True)
        return 0
    motions = ["poses", "commands"] if args.motion == "both" else [args.motion]
    if args.table:
        if min(args.at) < 0:
            ap.error("argument --at: trials are 0-based, at least 0")
        noises = {"exact": (False,), "noisy": (True,), "both": (False, True)}[args.poses]
        rows = table(args.kinds, args.table, args.first_seed, sorted(args.at), motions, noises)
        if args.json:
            args.json.write_text(json.dumps(rows))
        return 0
    if len(motions) > 1:
        ap.error("argument --motion: both only with --table")
    trials = args.trials or 100
    rows = []
    print(f"{'member':<16} {'n':>2} {'free':>7} {'filtered':>9} {'ratio':>6} {'within 2x':>9} "
          f"{'overlaps':>8} {'least':>6} {'changed, first / last 10':>25}")
    for kind in args.kinds:
        for noise, seeds in ((False, args.seeds), (True, args.noisy_seeds)):
            for seed in range(args.first_seed, args.first_seed + seeds):
                r = member(kind, seed, noise, trials, motions[0])
                rows.append(r)
                last_safe, last_free = r["safe"][-1], r["free"][-1]
                ok = last_safe <= 2 * last_free
                print(f"{kind + '-' + str(seed) + (' noisy' if noise else ''):<16} "
                      f"{r['robots']:>2} {last_free:7.3f} {last_safe:9.3f} "
                      f"{last_safe / last_free:6.2f} {'yes' if ok else 'no':>9} "
                      f"{r['overlaps']:>8} {r['least']:6.3f} "
                      f"{r['changed'][0]:>12.0f} / {np.mean(r['changed'][-10:]):<10.1f}",
                      flush=True)
    for noise in (False, True):
        part = [r for r in rows if r["noise"] == noise]
        if not part:
            continue
        within = sum(r["safe"][-1] <= 2 * r["free"][-1] for r in part)
        print(f"{'noisy' if noise else 'exact poses'}: {len(part)} members, "
              f"{sum(r['overlaps'] for r in part)} overlapping trials, within 2x of the "
              f"unfiltered run at the last trial: {within}, median filtered error "
              f"{np.median([r['safe'][-1] for r in part]):.3f} m (unfiltered "
              f"{np.median([r['free'][-1] for r in part]):.3f} m); without the filter "
              f"{sum(r['free_overlaps'] for r in part)} overlapping trials, in "
              f"{sum(r['free_overlaps'] > 0 for r in part)} members; the filter's changes, "
              f"trial 0 / mean of the last 10 (medians): "
              f"{np.median([r['changed'][0] for r in part]):.0f} / "
              f"{np.median([np.mean(r['changed'][-10:]) for r in part]):.1f}")
    if args.no_write or args.first_seed or args.motion != "poses":
        return 0
    FIG.mkdir(parents=True, exist_ok=True)
    (FIG / "families.json").write_text(json.dumps(rows))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(args.kinds), figsize=(13, 7), sharex=True, squeeze=False)
    for col, kind in enumerate(args.kinds):
        top, bottom = axes[0, col], axes[1, col]
        for r in rows:
            if r["kind"] != kind or r["noise"]:
                continue
            line, = top.semilogy(r["safe"], lw=1.2)
            top.semilogy(r["free"], lw=0.8, ls=":", color=line.get_color())
            bottom.plot(r["changed"], lw=1.0, color=line.get_color())
        top.set_title(f"{kind}: error, filtered (solid) and not (dotted)")
        top.set_ylabel("max position error [m]")
        bottom.set_ylabel("commands the filter changed")
        bottom.set_xlabel("trial")
        top.grid(True, which="both", alpha=0.3)
        bottom.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(FIG / "families.png", dpi=110)
    print(f"wrote {FIG / 'families.json'} and {FIG / 'families.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
