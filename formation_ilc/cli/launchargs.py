"""The options of ``formation-ilc launch`` (and ``run-file``), as a command-line parser.

Every argument is derived from the option table (``formation_ilc.config.option_table``):
its flag, type, choices, default, help and heading. The parser has no defaults
(``without_defaults``): what it parses holds only the options given, and each overrides
its key of a run file (``formation_ilc.cli.runfile``); every default is the table's, which
``plan.options.LaunchOptions`` starts from.
"""

from __future__ import annotations

import argparse
from typing import Any

from formation_ilc.cli.options import argument_of, cli_type
from formation_ilc.config.option_table import GROUPS, OPTIONS

__all__ = ["add_arguments", "launch_parser", "without_defaults", "argument_of", "cli_type"]


def without_defaults(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``p`` with no option defaults: what it parses holds only the options given, which
    override a run file's keys; every default is the option table's."""
    for action in p._actions:
        if action.dest != "help":
            action.default = argparse.SUPPRESS
    return p


def launch_parser() -> argparse.ArgumentParser:
    """The parser of ``formation-ilc launch``'s options (without defaults)."""
    from formation_ilc.cli.options import OneLineParser

    p = OneLineParser(prog="formation-ilc launch", add_help=False)
    add_arguments(p)
    return without_defaults(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Every row of the option table with a flag, under its heading of ``--help``: the
    options most runs need first, on one screen; the rest under headings for special
    runs (a run file documents every key)."""
    p._optionals.title = GROUPS[""]
    groups: dict[str, Any] = {"": p}
    for name, title in GROUPS.items():
        if name:
            groups[name] = p.add_argument_group(title)
    for opt in OPTIONS:
        if opt.flag is None:
            continue
        names, kw = argument_of(opt)
        groups[opt.group].add_argument(*names, **kw)
