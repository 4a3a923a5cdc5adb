"""Text from the wire made safe to print: no control characters reach a terminal.

A node's name, a contact's line, a watchdog's or clock's words come from messages any
member of the formation (or, without ``--secure``, any process on the domain) may write.
Printed as they are, an escape sequence would move the cursor, recolour or rewrite lines
of the launcher's console (a fake "every trial is in"). ``printable`` replaces every
control character (C0, DEL, C1: escape, carriage return, backspace, newline ...) with
its ``\\xNN`` / ``\\uNNNN`` escape and cuts the text to a length.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

__all__ = ["printable", "printable_tree"]

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def _escape(m: re.Match[str]) -> str:
    c = ord(m.group(0))
    return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"


def printable(text: Any, limit: int = 2000) -> str:
    """``text`` as a string with its control characters escaped, at most ``limit``
    characters of it (cut before escaping: an escape is never split)."""
    return _CONTROL.sub(_escape, str(text)[:limit])


def printable_tree(v: Any, limit: int = 2000, depth: int = 8) -> Any:
    """``v`` (JSON-like: mappings, lists, scalars) with every string in it, keys too,
    made ``printable``; deeper than ``depth`` levels, what is left becomes a string."""
    if isinstance(v, str):
        return printable(v, limit)
    if depth <= 0:
        return printable(repr(v), limit)
    if isinstance(v, Mapping):
        return {printable(k, limit) if isinstance(k, str) else k:
                printable_tree(x, limit, depth - 1) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [printable_tree(x, limit, depth - 1) for x in v]
    return v
