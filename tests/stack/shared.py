"""Runs one multi-process test makes and another reads: a test that needs the insecure run
its secure twin is compared with takes the one an earlier test of its lane made with the
same options (tests/conftest.py: a lane runs in file order, in one test process), and
makes its own only when it runs alone (``pytest -k``, ``-n 0`` in another order)."""

from __future__ import annotations

from typing import Any

#: (what, options) -> metrics (trials x columns) of a finished run
RUNS: dict[tuple[str, tuple[str, ...]], Any] = {}
