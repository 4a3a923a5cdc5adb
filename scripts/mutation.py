#!/usr/bin/env python3
"""Mutation testing of the numerical core and msgs_schema (issue 11).

Mutants are made by cosmic-ray's operators (the `mutation` extra pins it): every arithmetic,
comparison, boolean, unary, constant, loop and exception-handler site of the modules below,
the numba kernels included (cosmic-ray rewrites the module's source text; mutmut 3 skips any
decorated function, so it would not touch one @njit kernel). Each mutant is then tested by
this script rather than by `cosmic-ray exec`, for speed on a small machine:

* the kernels run interpreted (NUMBA_DISABLE_JIT=1): no compilation per mutant;
* a parent process imports numpy, numba, pytest (and rclpy for msgs_schema) once and forks
  a child per mutant; the child imports the mutated module from memory (an import hook),
  so the working tree is never modified and two mutants can run at once;
* each module has its own selection of fast tests (MODULES below), run with -x.

A mutant is killed when its tests fail (or fail to import), or when they run past the
timeout (3x the unmutated run, +10 s); it survives when they pass. Mutations that only
change type annotations (not evaluated: `from __future__ import annotations`) or remove
`@njit` or its cache flag (the same function) are equivalent by construction, not run.

Usage:
  python scripts/mutation.py                    # all modules, 2 jobs
  python scripts/mutation.py --module law --jobs 1
  python scripts/mutation.py --markdown         # the survivors table of docs/testing.md,
                                                # from the last results file
Results: .mutation/results.json (git-ignored). Exit status 1 when the score is below
--fail-under (default 90).
"""

from __future__ import annotations

import os

os.environ["NUMBA_DISABLE_JIT"] = "1"  # before numba is imported, here and in the children
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

import argparse  # noqa: E402
import ast  # noqa: E402
import difflib  # noqa: E402
import importlib.abc  # noqa: E402
import importlib.machinery  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict, dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / ".mutation" / "results.json"
REASONS = REPO / "scripts" / "mutation_reasons.json"

# module -> (file, import name, tests). Tests: fast ones that exercise the module, run
# interpreted; -m excludes the slow and multi-process tiers.
T = "tests/"
MODULES: dict[str, tuple[str, str, list[str]]] = {
    "law": ("formation_ilc/core/law.py", "formation_ilc.core.law",
            [T + "core/test_law.py", T + "core/test_reference.py"]),
    "delays": ("formation_ilc/core/delays.py", "formation_ilc.core.delays",
               [T + "core/test_delay_models.py", T + "core/test_delays.py",
                T + "core/test_reference.py"]),
    "topology": ("formation_ilc/core/topology.py", "formation_ilc.core.topology",
                 [T + "core/test_topology.py", T + "core/test_reference.py"]),
    "checks": ("formation_ilc/model/checks.py", "formation_ilc.model.checks",
               [T + "model/test_checks.py", T + "core/test_topology.py",
                T + "core/test_reference.py"]),
    "trajectory": ("formation_ilc/core/trajectory.py", "formation_ilc.core.trajectory",
                   [T + "core/test_trajectory.py", T + "core/test_reference.py"]),
    "kinematics": ("formation_ilc/core/kinematics.py", "formation_ilc.core.kinematics",
                   [T + "core/test_kinematics.py", T + "core/test_reference.py",
                    T + "core/test_trajectory.py"]),
    "simulate": ("formation_ilc/model/simulate.py", "formation_ilc.model.simulate",
                 [T + "model/test_simulate.py", T + "core/test_reference.py",
                  T + "core/test_pcg.py"]),
    "scenario": ("formation_ilc/config/scenario.py", "formation_ilc.config.scenario",
                 [T + "config/test_scenario_defaults.py", T + "config/test_scenario.py"]),
    "uncertainty": ("formation_ilc/core/uncertainty.py", "formation_ilc.core.uncertainty",
                    [T + "core/test_uncertainty_draws.py", T + "model/test_simulate.py",
                     T + "config/test_scenario.py", T + "core/test_delays.py",
                     T + "core/test_pcg.py"]),
    # numpy's SeedSequence/PCG64/random() in numba (run interpreted here: test_pcg takes
    # about 12 s unmutated, most mutants die in its first seconds)
    "pcg": ("formation_ilc/core/pcg.py", "formation_ilc.core.pcg",
            [T + "core/test_pcg.py", T + "core/test_uncertainty_draws.py"]),
    "msgs_schema": ("msgs_schema/convert.py", "msgs_schema.convert",
                    [T + "msgs_schema/test_convert.py"]),
    # the robot as a pure learner and the link rules it shares with the emulator
    "clock": ("formation_ilc/core/clock.py", "formation_ilc.core.clock",
              [T + "protocol/test_learner.py", T + "msgs_schema/test_convert.py"]),
    "links": ("formation_ilc/core/links.py", "formation_ilc.core.links",
              [T + "protocol/test_learner.py", T + "msgs_schema/test_convert.py"]),
    "learner": ("formation_ilc/protocol/learner.py", "formation_ilc.protocol.learner",
                [T + "protocol/test_learner.py"]),
    # the leader's trial protocol (tests/stack/test_faults.py drives it across processes: not
    # run per mutant)
    "schedule": ("formation_ilc/protocol/schedule.py", "formation_ilc.protocol.schedule",
                 [T + "protocol/test_follower.py", T + "protocol/test_schedule.py"]),
    "leader": ("formation_ilc/protocol/leader.py", "formation_ilc.protocol.leader",
               [T + "protocol/test_leader.py"]),
    # the cores of the simulator, the link emulator and the Pioneer bridge nodes
    "plant": ("formation_ilc/protocol/plant.py", "formation_ilc.protocol.plant",
              [T + "protocol/test_plant.py", T + "protocol/test_follower.py"]),
    "linkemu": ("formation_ilc/protocol/linkemu.py", "formation_ilc.protocol.linkemu",
                [T + "protocol/test_linkemu.py", T + "protocol/test_plant.py",
                 T + "protocol/test_follower.py"]),
    "bridge": ("formation_ilc/protocol/bridge.py", "formation_ilc.protocol.bridge",
               [T + "protocol/test_bridge.py", T + "protocol/test_follower.py"]),
    "wallclock": ("formation_ilc/protocol/wallclock.py", "formation_ilc.protocol.wallclock",
                  [T + "protocol/test_bridge.py", T + "protocol/test_follower.py"]),
}
PYTEST_ARGS = ["-x", "-q", "-p", "no:cacheprovider", "-n", "0",  # one process: the import hook
               "-m", "not slow and not multiprocess",
               # compares compiled with interpreted: meaningless with the JIT disabled
               "--deselect", T + "core/test_law.py::test_compiled_law_equals_interpreted_law"]

# operators: cosmic-ray's, narrowed to one replacement per arithmetic operator (+ <-> -,
# * <-> /, // -> /, % -> //, ** -> *) and to the negation and the boundary shift of each
# comparison (< -> >=, < -> <=, ...); replacing arithmetic by bitwise operators, or a
# comparison by `is`, mostly gives a TypeError at once: more run time, no information
_KEEP_BINARY = {"Add": "Sub", "Sub": "Add", "Mul": "Div", "Div": "Mul", "FloorDiv": "Div",
                "Mod": "FloorDiv", "Pow": "Mul"}
_KEEP_COMPARISON = {"Lt": ("GtE", "LtE"), "LtE": ("Gt", "Lt"), "Gt": ("LtE", "GtE"),
                    "GtE": ("Lt", "Gt"), "Eq": ("NotEq",), "NotEq": ("Eq",),
                    "Is": ("IsNot",), "IsNot": ("Is",)}


def operator_used(short: str) -> bool:
    m = re.match(r"Replace(Binary|Comparison)Operator_(\w+)_(\w+)$", short)
    if m is None:
        return not re.match(r"ReplaceUnaryOperator_\w+_(Invert|Not)$", short)
    kind, src, dst = m.groups()
    if kind == "Binary":
        return _KEEP_BINARY.get(src) == dst
    return dst in _KEEP_COMPARISON.get(src, ())


@dataclass
class Mutant:
    module: str
    operator: str
    occurrence: int
    line: int
    col: int
    definition: str | None
    diff: str
    outcome: str = "pending"  # killed | timeout | survived | equivalent
    seconds: float = 0.0


def _strip_annotations(tree: ast.AST) -> str:
    for node in ast.walk(tree):
        if isinstance(node, ast.arg):
            node.annotation = None
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            node.returns = None
        elif isinstance(node, ast.AnnAssign):
            node.annotation = ast.Constant(None)
    return ast.dump(tree)


def enumerate_mutants(name: str) -> tuple[list[Mutant], dict[int, str]]:
    """Every mutant of a module (with cosmic-ray's operators) and its mutated source by
    index; equivalent-by-construction ones are marked, with no source."""
    import cosmic_ray.plugins as plugins
    from cosmic_ray.ast import ast_nodes, get_ast
    from cosmic_ray.ast.ast_query import ASTQuery
    from cosmic_ray.mutating import mutate_code

    rel, _, _ = MODULES[name]
    source = (REPO / rel).read_text()
    lines = source.splitlines()
    base = _strip_annotations(ast.parse(source))
    mutants: list[Mutant] = []
    codes: dict[int, str] = {}
    for op_name in plugins.operator_names():
        short = op_name.split("/")[-1]
        op_cls = plugins.get_operator(op_name)
        if op_cls.arguments() or not operator_used(short):
            continue
        op = op_cls()
        positions = [(node, s, e) for node in ast_nodes(get_ast(source))
                     for s, e in op.mutation_positions(node)]
        for occ, (node, start, _end) in enumerate(positions):
            code = mutate_code(source, op, occ)
            if code is None:
                continue
            diff = "\n".join(ln for ln in difflib.unified_diff(
                lines, code.splitlines(), lineterm="", n=0) if ln[:1] in "+-"
                and not ln.startswith(("+++", "---")))
            m = Mutant(name, short, occ, start[0], start[1],
                       ASTQuery(node).get_definition_name(), diff)
            try:
                same = _strip_annotations(ast.parse(code)) == base
            except SyntaxError:
                same = False
            # @njit removed, or its cache=True flipped: the same function (run interpreted
            # here; compiled, it computes the same)
            njit_only = "@njit" in lines[start[0] - 1] and short in ("RemoveDecorator",
                                                                      "ReplaceTrueWithFalse")
            if same or njit_only:
                m.outcome = "equivalent"
            else:
                codes[len(mutants)] = code
            mutants.append(m)
    return mutants, codes


class _Loader(importlib.machinery.SourceFileLoader):
    def __init__(self, fullname: str, path: str, code: str):
        super().__init__(fullname, path)
        self._code = code

    def get_code(self, fullname):  # type: ignore[override]
        return compile(self._code, self.path, "exec", dont_inherit=True)


class _Override(importlib.abc.MetaPathFinder):
    """Imports one module from a source string instead of its file."""

    def __init__(self, fullname: str, path: Path, code: str):
        self.fullname, self.path, self.code = fullname, path, code

    def find_spec(self, fullname, path=None, target=None):
        if fullname != self.fullname:
            return None
        pkg = [str(self.path.parent)] if self.path.name == "__init__.py" else None
        return importlib.util.spec_from_file_location(
            fullname, self.path, loader=_Loader(fullname, str(self.path), self.code),
            submodule_search_locations=pkg)


def _child(name: str, code: str | None) -> None:
    """In a forked child: import the mutant (if any), run the tests, exit with pytest's
    status."""
    import pytest

    rel, mod, tests = MODULES[name]
    sys.dont_write_bytecode = True
    if code is not None:
        sys.meta_path.insert(0, _Override(mod, REPO / rel, code))
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    os.chdir(REPO)
    rc = pytest.main(PYTEST_ARGS + tests)
    os._exit(int(rc))


def _preload(names: list[str]) -> None:
    import numba  # noqa: F401
    import numpy  # noqa: F401
    import pytest  # noqa: F401
    import yaml  # noqa: F401

    if {"msgs_schema", "clock", "links"} & set(names):  # their tests import msgs_schema
        import rclpy  # noqa: F401
        import rclpy.qos  # noqa: F401


def _spawn(name: str, code: str | None) -> int:
    pid = os.fork()
    if pid == 0:
        try:
            _child(name, code)
        finally:
            os._exit(99)
    return pid


def baseline(name: str) -> float:
    t0 = time.perf_counter()
    pid = _spawn(name, None)
    _, status = os.waitpid(pid, 0)
    rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        raise SystemExit(f"{name}: the unmutated tests fail (pytest status {rc}); "
                         f"run: NUMBA_DISABLE_JIT=1 pytest {' '.join(MODULES[name][2])}")
    return time.perf_counter() - t0


def run(names: list[str], jobs: int) -> list[Mutant]:
    _preload(names)
    import formation_ilc

    if Path(formation_ilc.__file__).resolve().parents[1] != REPO:
        raise SystemExit(f"formation_ilc imports from {formation_ilc.__file__}, not this tree")
    del sys.modules["formation_ilc"]  # the children import it afresh
    todo: list[tuple[Mutant, str, float]] = []
    everything: list[Mutant] = []
    for name in names:
        mutants, codes = enumerate_mutants(name)
        limit = 3 * baseline(name) + 10
        n_eq = sum(m.outcome == "equivalent" for m in mutants)
        print(f"{name}: {len(mutants)} mutants ({n_eq} equivalent by construction), "
              f"timeout {limit:.0f} s", flush=True)
        everything += mutants
        todo += [(mutants[i], code, limit) for i, code in codes.items()]
    running: dict[int, tuple[Mutant, float, float]] = {}
    done = 0
    t_start = time.perf_counter()
    while todo or running:
        while todo and len(running) < jobs:
            m, code, limit = todo.pop(0)
            running[_spawn(m.module, code)] = (m, time.perf_counter(), limit)
        pid, status = os.waitpid(-1, os.WNOHANG)
        now = time.perf_counter()
        if pid == 0:
            for p, (m, t0, limit) in list(running.items()):
                if now - t0 > limit:
                    os.kill(p, signal.SIGKILL)
                    os.waitpid(p, 0)
                    m.outcome, m.seconds = "timeout", now - t0
                    del running[p]
                    done += 1
            time.sleep(0.01)
            continue
        m, t0, _ = running.pop(pid)
        rc = os.waitstatus_to_exitcode(status)
        if rc in (4, 5, 99):
            raise SystemExit(f"test run broken for {m.module} (pytest status {rc})")
        m.outcome = "survived" if rc == 0 else "killed"
        m.seconds = now - t0
        done += 1
        if done % 50 == 0:
            print(f"  {done} run, {now - t_start:.0f} s", flush=True)
    return everything


def score_table(mutants: list[Mutant]) -> list[str]:
    rows = ["| module | mutants run | killed | timeout | survived | score |",
            "| --- | ---: | ---: | ---: | ---: | ---: |"]
    tot = {"killed": 0, "timeout": 0, "survived": 0}
    for name in MODULES:
        ms = [m for m in mutants if m.module == name]
        if not ms:
            continue
        c = {k: sum(m.outcome == k for m in ms) for k in tot}
        for k in tot:
            tot[k] += c[k]
        n = sum(c.values())
        rows.append(f"| {name} | {n} | {c['killed']} | {c['timeout']} | {c['survived']} | "
                    f"{100 * (n - c['survived']) / max(n, 1):.1f}% |")
    n = sum(tot.values())
    rows.append(f"| **all** | {n} | {tot['killed']} | {tot['timeout']} | {tot['survived']} | "
                f"**{100 * (n - tot['survived']) / max(n, 1):.1f}%** |")
    return rows


def survivors_table(mutants: list[Mutant]) -> list[str]:
    """Every survivor with its reason: the first pattern of scripts/mutation_reasons.json
    that matches "module:line:operator: diff", else a test still to write."""
    reasons = json.loads(REASONS.read_text()) if REASONS.exists() else []
    rows = ["| where | mutation | why it survives |", "| --- | --- | --- |"]
    for m in sorted((m for m in mutants if m.outcome == "survived"),
                    key=lambda m: (list(MODULES).index(m.module), m.line, m.operator)):
        text = f"{m.module}:{m.line}:{m.operator}: {m.diff}"
        reason = next((r["reason"] for r in reasons if re.search(r["match"], text, re.S)),
                      "not equivalent: a test still to write")
        change = " / ".join(f"`{ln[1:].strip()}`" for ln in m.diff.splitlines()
                            if ln.startswith("+"))
        if len(change) > 120:
            change = change[:117] + "...`"
        rows.append(f"| {m.module}:{m.line} | {m.operator.replace('Operator_', ' ')}: "
                    f"{change.replace('|', '&#124;')} | {reason} |")
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--module", action="append", choices=list(MODULES),
                    help="only these modules (repeatable; default all)")
    ap.add_argument("--jobs", type=int, default=2, help="mutants run at once (default 2)")
    ap.add_argument("--fail-under", type=float, default=90.0, help="score %% (default 90)")
    ap.add_argument("--markdown", action="store_true",
                    help="print the tables for docs/testing.md from the last results")
    args = ap.parse_args()
    if args.markdown:
        data = json.loads(OUT.read_text())
        mutants = [Mutant(**m) for m in data["mutants"]]
        print("\n".join(score_table(mutants)))
        print()
        print("\n".join(survivors_table(mutants)))
        return 0
    names = args.module or list(MODULES)
    t0 = time.perf_counter()
    mutants = run(names, args.jobs)
    wall = time.perf_counter() - t0
    OUT.parent.mkdir(exist_ok=True)
    old = json.loads(OUT.read_text())["mutants"] if OUT.exists() and args.module else []
    kept = [m for m in old if m["module"] not in names]
    OUT.write_text(json.dumps({"seconds": wall, "jobs": args.jobs,
                               "mutants": kept + [asdict(m) for m in mutants]}, indent=1))
    print("\n".join(score_table(mutants)))
    print("\n".join(survivors_table(mutants)))
    ran = [m for m in mutants if m.outcome != "equivalent"]
    score = 100 * sum(m.outcome != "survived" for m in ran) / max(len(ran), 1)
    print(f"score {score:.1f}% over {len(ran)} mutants in {wall:.0f} s with {args.jobs} jobs")
    return 0 if score >= args.fail_under else 1


if __name__ == "__main__":
    sys.exit(main())
