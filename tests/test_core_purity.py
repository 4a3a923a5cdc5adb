"""Every layer below the nodes imports without ROS (STYLE habit 1), and the layers depend one
way: a module imports only from its own layer and the layers below it
(docs/architecture.md).

"Imports" means every way a module can reach another: an import at the top, one inside a
function (the lazy imports that keep a module quick to load), a module named in a string
(``python -m formation_ilc.system.delayer``, ``importlib.import_module("...")``), and code
in a string (``python -c "from x import y"``). The ROS packages of the project
(``msgs_schema``, ``robot_sim``, ``virtual_leader``) are layers too, where they sit."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import formation_ilc

PACKAGE = Path(formation_ilc.__file__).parent
ROOT = PACKAGE.parent
#: bottom to top: ``formation_ilc``'s layers and the ROS packages where they sit
#: (``msgs_schema`` above the pure layers, the nodes' packages above ``nodes``; the two of
#: one level never import each other), ``cli`` above everything
LEVELS: list[tuple[str, ...]] = [
    ("system",), ("core",), ("config",), ("model",), ("store",), ("protocol",),
    ("recordings",), ("studies",), ("plan",), ("msgs_schema",), ("nodes",),
    ("robot_sim", "virtual_leader"), ("cli",)]
LAYERS = [name for level in LEVELS for name in level]
#: the project's own ROS packages (top-level, beside formation_ilc)
ROS_PACKAGES = ("msgs_schema", "robot_sim", "virtual_leader")
#: formation_ilc's subpackages that must not import ROS, not even inside a function: all
#: but the nodes (cli reaches ROS only through them)
ROS_FREE = [layer for layer in LAYERS if layer not in ("nodes", *ROS_PACKAGES)]
_DOTTED = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+")


def _level(layer: str) -> int:
    return next(i for i, level in enumerate(LEVELS) if layer in level)


def _files(layer: str) -> list[Path]:
    folder = ROOT / layer if layer in ROS_PACKAGES else PACKAGE / layer
    return sorted(folder.rglob("*.py"))


def _modules(layer: str) -> list[str]:
    return sorted(f"formation_ilc.{layer}." + p.stem for p in (PACKAGE / layer).glob("*.py")
                  if p.stem not in ("__init__", "__main__"))


def _is_ros(module: str) -> bool:
    top = module.split(".")[0]
    return (top in ("rclpy", "rosidl_runtime_py", "ament_index_python", *ROS_PACKAGES)
            or top.endswith(("_msgs", "_srvs", "_interfaces")))


def references(path: Path) -> set[str]:
    """Every module ``path`` reaches: absolute imports anywhere in it (in a function too),
    dotted module names in strings, and imports in strings that are code."""
    found: set[str] = set()

    def walk(tree: ast.AST, strings: bool) -> None:
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module)
                found.update(f"{node.module}.{a.name}" for a in node.names)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif strings and isinstance(node, ast.Constant) and isinstance(node.value, str):
                text = node.value.strip()
                if _DOTTED.fullmatch(text):
                    found.add(text)
                elif "import" in text:
                    try:
                        walk(ast.parse(text), strings=False)
                    except (SyntaxError, ValueError):
                        pass  # prose

    walk(ast.parse(path.read_text()), strings=True)
    return found


def _layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] in ROS_PACKAGES:
        return parts[0]
    if parts[0] == "formation_ilc" and len(parts) > 1 and parts[1] in LAYERS:
        return parts[1]
    return None


def test_every_layer_but_the_nodes_imports_without_rclpy():
    mods = [m for layer in ROS_FREE for m in _modules(layer)]
    assert len(mods) > 30
    code = (
        "import sys\n"
        "for m in ('rclpy', 'rclpy.node', 'geometry_msgs', 'nav_msgs', 'std_msgs'):\n"
        "    sys.modules[m] = None\n"
        f"for m in {mods!r}:\n"
        "    __import__(m)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_no_pure_layer_reaches_ros_even_inside_a_function():
    reached = [f"{path.relative_to(ROOT)} reaches {module}"
               for layer in ROS_FREE for path in _files(layer)
               for module in sorted(references(path)) if _is_ros(module)]
    assert not reached, reached


def test_layers_import_only_downwards():
    assert sorted(p.name for p in PACKAGE.iterdir()
                  if p.is_dir() and (p / "__init__.py").exists()) == sorted(
        layer for layer in LAYERS if layer not in ROS_PACKAGES)
    upward = []
    for layer in LAYERS:
        for path in _files(layer):
            for module in sorted(references(path)):
                other = _layer_of(module)
                if other is not None and _level(other) > _level(layer):
                    upward.append(f"{path.relative_to(ROOT)} reaches {module}")
    assert not upward, upward


def test_the_checks_see_what_hides_in_functions_and_strings(tmp_path):
    """A lazy import, a module started by name and code in a string all count."""
    src = tmp_path / "m.py"
    src.write_text(
        "def f():\n"
        "    import rclpy\n"
        "    from msgs_schema import wire\n"
        "ARGV = ['python', '-m', 'robot_sim.node']\n"
        "CODE = 'from virtual_leader.node import main; main()'\n"
        "NODE = 'robot_sim'  # a node's name, not a module\n")
    got = references(src)
    assert {"rclpy", "msgs_schema", "robot_sim.node", "virtual_leader.node"} <= got
    assert "robot_sim" not in got
    assert [_layer_of(m) for m in ("robot_sim.node", "formation_ilc.cli.plan", "numpy")] == [
        "robot_sim", "cli", None]
    assert _is_ros("geometry_msgs.msg") and _is_ros("msgs_schema") and not _is_ros("numpy")


def test_no_relative_import_reaches_outside_its_layer():
    paths = [*PACKAGE.rglob("*.py"), *(p for pkg in ROS_PACKAGES for p in _files(pkg))]
    assert len(paths) > 90
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert node.level <= 1, f"{path}: from {'.' * node.level}{node.module}"


def test_every_module_is_in_the_architecture():
    """docs/architecture.md names every module in its layer's row (or its package's)."""
    rows: dict[str, str] = {}
    for line in (ROOT / "docs" / "architecture.md").read_text().splitlines():
        m = re.match(r"\| `(\w+)`(?:, `(\w+)`)? \|", line)
        for layer in (m.groups() if m else ()):
            if layer:
                rows[layer] = rows.get(layer, "") + line
    assert set(LAYERS) <= set(rows)
    missing = [f"{layer}/{path.stem}" for layer in LAYERS for path in _files(layer)
               if path.stem not in ("__init__", "__main__")
               and f"`{path.stem}`" not in rows[layer]]
    assert not missing, missing
