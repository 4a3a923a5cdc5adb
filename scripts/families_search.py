#!/usr/bin/env python3
"""Search the families for the member the safety filter slows most (docs/safety.md,
"Judged on families").

    .venv/bin/python scripts/families_search.py [--seed 0] [--trial 30] [--motion poses]
        [--kinds orbit tusi ...] [--random 40] [--local 60] [--starts 3] [--show 10]
        [--out docs/figures/families_worst.yaml]

Random members of the families (``studies.families``, with and without the paper's
noise, each fitting a P3-DX team), then a local search over the worst few's continuous
parameters (speed, spacing, periods, phases; every step must still fit), judged by the
error through the filter over the error without it at trial ``--trial`` (0-based), cold
starts in the batch simulator (``studies.families.search``). Prints every member judged, the
worst ``--show`` with their ratios, and writes the worst member's scenario file to
``--out``. Deterministic for ``--seed``. About 0.5-2 s a member on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from formation_ilc.studies.families import KINDS, search  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trial", type=int, default=30, help="the judged trial (0-based)")
    ap.add_argument("--motion", choices=("poses", "commands"), default="poses",
                    help="the filter's estimate of the other robots' motion")
    ap.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    ap.add_argument("--random", type=int, default=40, help="random members")
    ap.add_argument("--local", type=int, default=60, help="local steps in all")
    ap.add_argument("--starts", type=int, default=3, help="worst members searched about")
    ap.add_argument("--noise-share", type=float, default=0.5,
                    help="the share of random members with the paper's noise")
    ap.add_argument("--show", type=int, default=10)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" /
                    "families_worst.yaml")
    args = ap.parse_args()
    if args.trial < 0 or args.random < 1 or args.local < 0 or args.starts < 1:
        ap.error("--trial must be >= 0, --random and --starts >= 1, --local >= 0")
    judged = search(seed=args.seed, trial=args.trial, motion=args.motion, kinds=args.kinds,
                    random_budget=args.random, local_budget=args.local, starts=args.starts,
                    noise_share=args.noise_share, progress=lambda s: print(s, flush=True))
    if not judged:
        print("no member judged")
        return 1
    print(f"\nworst {min(args.show, len(judged))} of {len(judged)} judged (trial {args.trial}, "
          f"motion={args.motion}): error through the filter / without it")
    for m in judged[:args.show]:
        moved = ", ".join(f"{v:+.2f}" for v in m.x[:3])
        print(f"  {m.name:<28} n={m.data['robots']:<2} {m.safe:7.3f} / {m.free:7.3f} m  "
              f"ratio {m.ratio:6.2f}  log speed/spacing/period {moved}")
    worst = judged[0]
    head = (f"# The worst member found by scripts/families_search.py --seed {args.seed}\n"
            f"#   --trial {args.trial} --motion {args.motion} --random {args.random} "
            f"--local {args.local} --starts {args.starts}\n"
            f"#   --noise-share {args.noise_share} --kinds {' '.join(args.kinds)}\n"
            f"# {worst.name}: error at trial {args.trial} through the filter "
            f"{worst.safe:.3f} m against {worst.free:.3f} m without it "
            f"(ratio {worst.ratio:.2f}).\n"
            f"# Perturbation of the drawn member (studies.families.perturb):\n"
            f"#   {[round(v, 4) for v in worst.x]}\n")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(head + yaml.safe_dump(worst.data, sort_keys=False))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
