"""Reading a YAML file of the user's (a scenario, a sweep spec) safely, and its fields checked.

* ``read_text_file``: at most so many bytes of a regular file (not a FIFO, a device, a
  folder), UTF-8 text; ``parse_yaml``: the safe loader (YAML 1.2 numbers), with the
  document's depth and alias expansion bounded before it is built (a "billion laughs" is
  refused, not expanded).
* ``Fields``: a mapping read once, field by field, every value checked as it is read, and
  unknown keys an error; every error a ``ScenarioError`` that reads ``file: field: reason``.

``config.scenario`` builds a scenario with them; ``studies.sweep`` a sweep spec.
"""

from __future__ import annotations

import math
import os
import re
import reprlib
import stat
from pathlib import Path
from typing import Any

import yaml

from formation_ilc.core.guards import format_bytes

__all__ = ["ScenarioError", "Fields", "read_text_file", "parse_yaml", "show", "printable",
           "one_line", "deep_flow_end", "MAX_FILE_BYTES", "MAX_YAML_DEPTH", "MAX_YAML_SIZE"]

#: a scenario (or sweep spec) file larger than this is refused before it is read: parsing
#: YAML costs seconds per MiB. Long sampled references belong in a CSV file
#: (reference.file), which is read at C speed.
MAX_FILE_BYTES = 1 << 20
#: deepest nesting of YAML collections (a scenario needs 5)
MAX_YAML_DEPTH = 32
#: most nodes plus characters a YAML document may expand to through its aliases (*name):
#: a "billion laughs" expands a few hundred bytes to gigabytes, a scenario file to about
#: its own size
MAX_YAML_SIZE = 16 << 20
class ScenarioError(ValueError):
    """A scenario file is invalid. The message reads ``file: field: reason``."""


_repr = reprlib.Repr()
_repr.maxstring = 60
_repr.maxother = 60
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 6
_repr.maxlevel = 3


def show(value: Any) -> str:
    """A value for an error message: its repr, cut short (a field may hold megabytes)."""
    return _repr.repr(value)


def read_text_file(path: Path, limit: int = MAX_FILE_BYTES, what: str = "a scenario") -> str:
    """The text of a YAML file, read at most ``limit`` bytes; ScenarioError naming the file
    if it cannot be read, is larger than ``limit``, or is not UTF-8 text."""
    try:
        # without blocking: a FIFO would wait for a writer forever
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a device"
                    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a folder"
                    if stat.S_ISDIR(mode) else "not a regular file")
            raise ScenarioError(f"{path}: {kind}, not {what} file (a regular file is needed)")
        os.set_blocking(fd, True)
        with os.fdopen(fd, "rb") as fh:
            fd = -1
            data = fh.read(limit + 1)
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror or exc}") from None
    finally:
        if fd >= 0:
            os.close(fd)
    if len(data) > limit:
        raise ScenarioError(f"{path}: larger than {format_bytes(limit)}, the most {what} file "
                            f"may be (a long sampled reference belongs in a CSV file: "
                            f"reference.file)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not a text file: byte 0x{data[exc.start]:02x} at offset "
                            f"{exc.start} is not UTF-8 ({what} file is YAML text)") from None
    if "\x00" in text:
        raise ScenarioError(f"{path}: not a text file: it holds NUL bytes at offset "
                            f"{text.index(chr(0))} ({what} file is YAML text)")
    return text.removeprefix("\ufeff")


class _Loader(yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False)  # type: ignore[misc]
              else yaml.SafeLoader):
    """The safe loader (libyaml's when installed), which also reads 1e300 and 5E-3 as
    numbers, as YAML 1.2 does (YAML 1.1 wants a dot: 1.0e300)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _yaml_where(exc: yaml.YAMLError) -> str:
    mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
    return "" if mark is None else f"line {mark.line + 1}, column {mark.column + 1}: "


def printable(text: str, limit: int = 120) -> str:
    """A field path for a message: control characters escaped, cut short."""
    if not text.isprintable():
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def one_line(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _measure(text: str, source: str) -> None:
    """Refuse YAML nested deeper than MAX_YAML_DEPTH, with a recursive alias, or whose
    aliases expand it beyond MAX_YAML_SIZE, from its events alone (nothing is built; the C
    composer, which recurses on the C stack, only ever sees bounded nesting)."""
    loader = _Loader(text)
    sizes: dict[str, int] = {}
    # one frame per open collection: [anchor, size, is_mapping, position, expect_key]
    stack: list[list[Any]] = []

    def where() -> str:
        parts = ""
        for fr in stack:
            if fr[2]:
                parts += ("." if parts else "") + str(fr[3])
            else:
                parts += f"[{fr[3]}]"
        return one_line(parts, 60) or "top level"

    def add(size: int, key: str | None = None) -> None:
        if not stack:
            return
        fr = stack[-1]
        fr[1] += size
        if fr[1] > MAX_YAML_SIZE:
            raise ScenarioError(
                f"{source}: {where()}: the aliases (*name) expand the document beyond "
                f"{MAX_YAML_SIZE / 1e6:.3g} million nodes and characters (a 'billion "
                f"laughs'?); refused")
        if fr[2]:
            if fr[4]:
                fr[3] = key if key is not None else "?"
            fr[4] = not fr[4]
        else:
            fr[3] += 1

    try:
        while loader.check_event():
            ev = loader.get_event()
            if isinstance(ev, yaml.ScalarEvent):
                size = 1 + len(ev.value)
                if ev.anchor is not None:
                    sizes[ev.anchor] = size
                add(size, one_line(ev.value, 40))
            elif isinstance(ev, yaml.AliasEvent):
                if any(fr[0] == ev.anchor for fr in stack):
                    raise ScenarioError(f"{source}: {where()}: alias *{ev.anchor} refers to a "
                                        f"collection that contains it (recursive); refused")
                add(sizes.get(ev.anchor, 1))
            elif isinstance(ev, yaml.CollectionStartEvent):
                if len(stack) >= MAX_YAML_DEPTH:
                    mark = ev.start_mark
                    raise ScenarioError(f"{source}: line {mark.line + 1}: {where()}: nested "
                                        f"deeper than {MAX_YAML_DEPTH} levels; refused")
                stack.append([ev.anchor, 1, isinstance(ev, yaml.MappingStartEvent),
                              None if isinstance(ev, yaml.MappingStartEvent) else 0, True])
            elif isinstance(ev, yaml.CollectionEndEvent):
                anchor, size = stack.pop()[:2]
                if anchor is not None:
                    sizes[anchor] = size
                add(size)
    finally:
        loader.dispose()


_FLOW_MARKS = re.compile(r"""[\[\]{}'"#\n\\]""")


def deep_flow_end(text: str) -> int | None:
    """Where flow nesting could first pass MAX_YAML_DEPTH: the end of the bracket that opens
    level MAX_YAML_DEPTH + 1, counting ``[`` and ``{`` outside quotes and comments; None
    where no such bracket exists.

    The count is an upper bound (a bracket inside a plain scalar counts too), read from the
    text before any parser sees it: libyaml's scanner reads a run of flow openers ahead of
    its events and, from PyYAML 6.0.4 on, refuses 1000 of them with a message of its own,
    before ``_measure`` sees the event that is one level too deep."""
    depth = 0
    quote = ""
    comment = False
    skip = -1  # the character after a backslash in a double-quoted scalar
    for m in _FLOW_MARKS.finditer(text):
        i, c = m.start(), m.group()
        if i == skip:
            continue
        if comment:
            comment = c != "\n"
        elif quote:
            if quote == '"' and c == "\\":
                skip = i + 1
            elif c == quote:
                quote = ""
        elif c == "#" and (i == 0 or text[i - 1] in " \t\n"):
            comment = True
        elif c in "'\"" and (i == 0 or text[i - 1] in " \t\n[{,:-?"):
            quote = c  # a quote that starts a scalar (an apostrophe in a word does not)
        elif c in "[{":
            depth += 1
            if depth > MAX_YAML_DEPTH:
                return m.end()
        elif c in "]}":
            depth = max(depth - 1, 0)
    return None


def _measure_bounded(text: str, source: str) -> None:
    """``_measure``, with the depth bound applied before libyaml's own: where the text could
    nest deeper than MAX_YAML_DEPTH, the events of the text up to that bracket are measured
    first (a prefix has the same events as the whole, up to where it ends), so the same
    file gets the same message whatever libyaml is installed."""
    end = deep_flow_end(text)
    if end is not None:
        try:
            _measure(text[:end], source)
        except yaml.YAMLError:
            pass  # the cut text ends early: the whole text is measured next
    _measure(text, source)


def parse_yaml(text: str, source: str) -> Any:
    """The YAML document in ``text``, with its cost bounded before it is built (depth,
    recursive aliases, alias expansion); one-line ScenarioError naming ``source`` (and the
    line) otherwise."""
    try:
        _measure_bounded(text, source)
        return yaml.load(text, Loader=_Loader)  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or str(exc)
        context = getattr(exc, "context", None)
        why = one_line(f"{problem} ({context})" if context else problem)
        raise ScenarioError(f"{source}: not valid YAML: {_yaml_where(exc)}{why}") from None
    except (ValueError, OverflowError, RecursionError) as exc:
        if isinstance(exc, ScenarioError):
            raise
        # e.g. a date like 2024-13-45, an integer of 5000 digits
        raise ScenarioError(f"{source}: not valid YAML: {one_line(str(exc))}") from None


_DEG = re.compile(r"^\s*([-+]?[0-9.eE+-]+)\s*deg\s*$")


class Fields:
    """A mapping read once, field by field; unknown keys are an error."""

    def __init__(self, data: Any, path: str, src: str):
        if not isinstance(data, dict):
            raise ScenarioError(f"{src}: {path or 'top level'}: expected a mapping, "
                                f"got {show(data) if data is None else type(data).__name__}")
        self.data = data
        self.path = path
        self.src = src
        self.used: set[str] = set()

    def fail(self, key: str | None, why: str) -> ScenarioError:
        where = self.path if key is None else (f"{self.path}.{key}" if self.path else key)
        return ScenarioError(f"{self.src}: {printable(str(where))}: {why}")

    def get(self, key: str, default: Any = ..., *, required: bool = False) -> Any:
        self.used.add(key)
        if key not in self.data:
            if required or default is ...:
                raise self.fail(key, "required field is missing")
            return default
        return self.data[key]

    def sub(self, key: str, required: bool = True) -> Fields:
        val = self.get(key, required=required) if required else self.get(key, {})
        return Fields(val if val is not None else {}, f"{self.path}.{key}" if self.path else key,
                       self.src)

    def number(self, key: str, default: Any = ..., *, positive: bool = False,
               nonneg: bool = False, angle: bool = False) -> float:
        return self.as_number(self.get(key, default), key, positive=positive, nonneg=nonneg,
                              angle=angle)

    def as_number(self, v: Any, key: str, *, positive: bool = False, nonneg: bool = False,
                  angle: bool = False) -> float:
        if angle and isinstance(v, str) and (m := _DEG.match(v)):
            try:
                v = math.radians(float(m.group(1)))
            except ValueError:
                raise self.fail(key, f"cannot read {show(v)} as an angle") from None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            hint = " (a number, or a string like '0.05 deg')" if angle else ""
            raise self.fail(key, f"expected a number{hint}, got {show(v)}")
        v = float(v)
        if not math.isfinite(v):
            raise self.fail(key, f"must be finite, got {v}")
        if positive and v <= 0:
            raise self.fail(key, f"must be > 0, got {v}")
        if nonneg and v < 0:
            raise self.fail(key, f"must be >= 0, got {v}")
        return v

    def integer(self, key: str, default: Any = ..., *, minimum: int | None = None) -> int:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(key, f"expected an integer, got {show(v)}")
        if minimum is not None and v < minimum:
            raise self.fail(key, f"must be >= {minimum}, got {v}")
        return v

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None
               ) -> str:
        v = self.get(key, default)
        if not isinstance(v, str):
            raise self.fail(key, f"expected a string, got {show(v)}")
        if choices is not None and v not in choices:
            raise self.fail(key, f"must be one of {', '.join(choices)}; got {show(v)}")
        return v

    def numbers(self, key: str, length: int, default: Any = ..., *, nonneg: bool = False,
                angle_index: tuple[int, ...] = ()) -> tuple[float, ...]:
        v = self.get(key, default)
        if not isinstance(v, (list, tuple)) or len(v) != length:
            raise self.fail(key, f"expected a list of {length} numbers, got {show(v)}")
        return tuple(self.as_number(x, f"{key}[{i}]", nonneg=nonneg, angle=i in angle_index)
                     for i, x in enumerate(v))

    def robot(self, v: Any, key: str, n: int) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(key, f"expected a robot number, got {show(v)}")
        if not 1 <= v <= n:
            raise self.fail(key, f"robot {v} does not exist (robots are 1..{n})")
        return v

    def finish(self) -> None:
        extra = sorted(set(map(str, self.data)) - self.used)
        if extra:
            raise self.fail(extra[0], f"unknown field (known here: {', '.join(sorted(self.used))})")
