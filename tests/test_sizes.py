"""No function of the product over 80 lines, no file of it over 800 (issue 55).

"The product" is what is installed: the packages ``formation_ilc``, ``robot_sim``,
``virtual_leader`` and ``msgs_schema``. ``scripts/`` (benchmarks and studies run by hand),
``tests/`` and ``launch/`` are not product and are not scanned. Numba kernels are functions
like any other: a kernel is counted as written (``@njit`` bodies included).

A function's length is its lines from the ``def`` (decorators left out) to its last line,
its docstring included; a function nested in another counts in both.
"""

import ast
from pathlib import Path

import formation_ilc

ROOT = Path(formation_ilc.__file__).resolve().parents[1]
PRODUCT = ("formation_ilc", "robot_sim", "virtual_leader", "msgs_schema")
MAX_FUNCTION = 80
MAX_FILE = 800


def _files() -> list[Path]:
    return sorted(p for pkg in PRODUCT for p in (ROOT / pkg).rglob("*.py")
                  if "__pycache__" not in p.parts)


def _functions(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            assert node.end_lineno is not None
            out.append((f"{node.name}:{node.lineno}", node.end_lineno - node.lineno + 1))
    return out


def test_the_product_is_scanned() -> None:
    files = _files()
    for pkg in PRODUCT:
        assert any(p.relative_to(ROOT).parts[0] == pkg for p in files), pkg
    assert sum(len(_functions(p)) for p in files) > 1000


def test_no_function_over_80_lines() -> None:
    long = [f"{p.relative_to(ROOT)} {name} {n}" for p in _files()
            for name, n in _functions(p) if n > MAX_FUNCTION]
    assert not long, "functions over 80 lines:\n" + "\n".join(long)


def test_no_file_over_800_lines() -> None:
    big = [f"{p.relative_to(ROOT)} {n}" for p in _files()
           if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_FILE]
    assert not big, "files over 800 lines:\n" + "\n".join(big)
