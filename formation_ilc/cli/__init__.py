"""The command line: ``formation-ilc`` and its subcommands, the launcher and the analysis of
a recording. The top layer: it may import every other one."""

from formation_ilc.cli.commands import main

__all__ = ["main"]
