"""Command-line option types and checks shared by ``formation-ilc`` and its ``launch``.

Each type refuses a bad value while the arguments are parsed, so the user gets one line
(``error: argument --seed: must be an integer >= 0, got -1 (...)``) and exit status 2, not
a traceback from deep inside a run. ``OneLineParser`` prints argparse's errors that way.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from formation_ilc.plan.options import OptionError

__all__ = ["OneLineParser", "int_range", "nonneg_int", "positive_int", "positive_float",
           "out_dir_arg", "output_file_arg", "make_out_dir", "OptionError", "MAX_TRIAL",
           "add_run_options", "special_path", "fs_type", "nonneg_float", "scenario_arg",
           "paragraphs", "arg_type", "argument_of", "cli_type"]

from formation_ilc.config.option_table import Option
from formation_ilc.config.values import MAX_SEED, MAX_TRIAL, float_in, int_in


def arg_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type of a parser of ``config.values`` (ValueError -> argparse's error,
    so that the reason is printed, not argparse's "invalid value")."""

    def typed(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    typed.__name__ = getattr(parse, "__name__", "value")
    return typed


class OneLineParser(argparse.ArgumentParser):
    """argparse with its usage errors on one line: 'error: <why> (see PROG --help)'."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {message} (see {self.prog} --help)\n")


def int_range(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi]."""
    return arg_type(int_in(lo, hi))


nonneg_int = int_range(0, MAX_SEED)
positive_int = int_range(1, MAX_TRIAL)
#: an argparse type: a finite number > 0
positive_float = arg_type(float_in(0.0, open_lo=True))


def float_range(lo: float, hi: float, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite number in [lo, hi] (``unit`` named in the error)."""
    return arg_type(float_in(lo, hi, unit=unit))


#: an argparse type: a finite number >= 0
nonneg_float = arg_type(float_in(0.0))


def _writable_ancestor(path: Path) -> str | None:
    """Why a folder cannot be made at ``path``, judged without creating anything."""
    p = path.absolute()
    if p.exists() and not p.is_dir():
        return "exists and is not a folder"
    probe = p
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        return f"{probe} is not a folder"
    if not os.access(probe, os.W_OK | os.X_OK):
        return f"{probe} is not writable"
    return None


#: kernel file systems: what is written there is no file on a disk (/dev/full fails every
#: write, /proc and /sys hold the kernel's own controls)
PSEUDO_FS = frozenset({"proc", "sysfs", "devtmpfs", "devpts", "cgroup", "cgroup2", "debugfs",
                       "tracefs", "securityfs", "pstore", "bpf", "configfs", "fusectl",
                       "mqueue", "efivarfs", "binfmt_misc", "autofs", "nsfs", "rpc_pipefs"})


def fs_type(path: Path) -> str | None:
    """The file system type that ``path`` (resolved; or its nearest existing ancestor) is
    on, from /proc/self/mountinfo; None when that cannot be read."""
    try:
        with open("/proc/self/mountinfo", encoding="utf-8", errors="replace") as fh:
            lines = fh.read(4 << 20).splitlines()
    except OSError:
        return None
    p = Path(os.path.realpath(path))
    best, kind = "", None
    for line in lines:
        left, _, right = line.partition(" - ")
        fields, rest = left.split(), right.split()
        if len(fields) < 5 or not rest:
            continue
        mount = fields[4].replace("\\040", " ")
        if (p == Path(mount) or Path(mount) in p.parents) and len(mount) >= len(best):
            best, kind = mount, rest[0]
    return kind


def special_path(path: Path, want: str) -> str | None:
    """Why ``path`` cannot be an output (``want``: 'file' or 'folder'): an existing device,
    FIFO or socket, or a place on a kernel file system (/proc, /sys, /dev); None if it
    can be one."""
    import stat

    from formation_ilc.store.bounded import kind_of

    try:
        st = os.stat(path)
    except OSError:
        st = None
    if st is not None and not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        return f"is {kind_of(st.st_mode)}, not a regular {want}"
    kind = fs_type(path)
    if kind in PSEUDO_FS:
        return (f"is on {kind}, a kernel file system, not a disk (nothing written there is "
                f"kept as a {want})")
    return None


def out_dir_arg(text: str) -> Path:
    """An argparse type: a folder that exists or can be created (not a file)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty folder name")
    path = Path(text)
    # a folder on /proc or /sys cannot be made: make_out_dir says so when it tries
    why = _writable_ancestor(path)
    if why is not None:
        raise argparse.ArgumentTypeError(f"{text}: {why}")
    return path


def output_file_arg(text: str) -> Path:
    """An argparse type: a regular file to write (not a device, a FIFO, a file of /proc),
    in a folder that exists or can be created."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty file name")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder, expected a file name")
    why = special_path(path, "file") or _writable_ancestor(path.parent)
    if why is not None:
        raise argparse.ArgumentTypeError(f"{text}: {why}")
    return path


out_dir_arg.__name__ = "folder"
output_file_arg.__name__ = "file"


def cli_type(opt: Option) -> Any:
    """The argparse type of a row: its own parser (the choices left to argparse), and for a
    folder or a file to write, the command line's check that it can be written."""
    if opt.kind == "folder":
        return out_dir_arg
    if opt.kind == "file":
        return output_file_arg
    if opt.kind == "path":
        return Path
    if opt.kind in ("int", "port", "float"):
        return arg_type(opt.value)
    return None


def argument_of(opt: Option) -> tuple[tuple[str, ...], dict[str, Any]]:
    """The ``add_argument`` call of a row: its names and keywords."""
    kw: dict[str, Any] = {"help": opt.help_text().replace("%", "%%")}
    if opt.kind == "bool":
        kw.update(action="store_true", default=bool(opt.default))
    elif opt.kind == "switch":
        kw.update(action=argparse.BooleanOptionalAction, default=opt.default)
    else:
        kw.update(default=list(opt.default) if isinstance(opt.default, tuple) else opt.default,
                  metavar=opt.metavar)
        if cli_type(opt) is not None:
            kw["type"] = cli_type(opt)
        if opt.choices is not None:
            kw["choices"] = opt.choices
            kw.pop("metavar")
        if opt.kind == "names":
            kw["nargs"] = "+"
        elif opt.kind == "port":
            kw.update(nargs="?", const=opt.const)
        elif not (opt.flag or "").startswith("-"):
            kw["nargs"] = "?"
    if not (opt.flag or "").startswith("-"):
        return (opt.field,), kw
    return (opt.flag or "",), kw


def add_run_options(p: argparse.ArgumentParser, *, law: bool = True,
                    trials: int | None = None, shape: bool = False) -> None:
    """The options of a run that ``simulate``, ``compare`` and ``launch`` share, as the
    option table declares them: --trials (default ``trials``, else the scenario's), --law
    and --memory (with ``law``), --seed, --no-noise, --no-delay; with ``shape`` the
    reference's --headings and --time-scale."""
    from formation_ilc.config.option_table import option

    names = ["trials", *(("law", "memory") if law else ()), "seed", "no_noise", "no_delay",
             *(("headings", "time_scale") if shape else ())]
    for name in names:
        flags, kw = argument_of(option(name))
        if name == "trials" and trials != kw["default"]:
            kw.update(default=trials, help=kw["help"].replace(
                f"(default {kw['default']})", "(default: the scenario's 'trials')"
                if trials is None else f"(default {trials})"))
        p.add_argument(*flags, **kw)


def make_out_dir(path: Path, option: str = "--out") -> Path:
    """Create the output folder ``path`` and prove it writable; OptionError naming the
    option and the reason (a file in the way, no permission, a read-only file system)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        why = "exists and is not a folder" if isinstance(exc, FileExistsError) else (
            exc.strerror or str(exc))
        raise OptionError(f"{option} {path}: cannot write there: {why}") from None
    return path


def fail(message: str, status: int = 2) -> int:
    """Print 'error: message' on stderr and return ``status`` (for a command's return)."""
    print(f"error: {message}", file=sys.stderr)
    return status


def paragraphs(text: str) -> str:
    """Paragraphs (separated by blank lines) wrapped to 88 columns, for raw help text."""
    import textwrap

    return "\n\n".join(textwrap.fill(" ".join(par.split()), 88) for par in text.split("\n\n"))


def scenario_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO",
                   help="built-in scenario name (formation-ilc scenarios) or a YAML file")
