"""The console scripts' old names, kept for one release: each says it was renamed (to the
name of its node, ``formation-ilc-<node name>``) and runs the new one with the same
arguments.

    formation-ilc-sim ...   ->  formation-ilc-robot-sim ...
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

__all__ = ["RENAMED", "main"]

#: old console script -> new (the node's name)
RENAMED = {
    "formation-ilc-sim": "formation-ilc-robot-sim",
    "formation-ilc-physics": "formation-ilc-physics-sim",
    "formation-ilc-links": "formation-ilc-link-emulator",
    "formation-ilc-leader": "formation-ilc-virtual-leader",
    "formation-ilc-record": "formation-ilc-recorder",
}


def deprecation(old: str, new: str) -> str:
    return (f"{old}: renamed {new} (the name of its node); the old name goes away in the "
            f"next release")


def main() -> int:
    old = Path(sys.argv[0]).name
    new = RENAMED.get(old)
    if new is None:
        print(f"{old}: not a renamed formation-ilc script (renamed: "
              f"{', '.join(RENAMED)})", file=sys.stderr)
        return 2
    print(deprecation(old, new), file=sys.stderr, flush=True)
    beside = Path(sys.argv[0]).with_name(new)
    exe = str(beside) if beside.exists() else shutil.which(new)
    if exe is None:
        print(f"{old}: {new} is not installed", file=sys.stderr)
        return 2
    os.execv(exe, [new, *sys.argv[1:]])
    return 0  # not reached
