"""formation-ilc: a team of differential-drive robots learns a formation by iterative
learning control (README.md).

``formation_ilc.run(...)`` runs a scenario on the batch simulator or the ROS 2 stack and
returns its metrics (``formation_ilc.cli.api``); it is loaded on first use, so importing a
layer of the package (as every node process does) loads nothing more.
"""

from typing import Any

__all__ = ["run", "RunResult", "RunFailed"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from formation_ilc.cli import api

        return getattr(api, name)
    raise AttributeError(f"module 'formation_ilc' has no attribute {name!r}")
