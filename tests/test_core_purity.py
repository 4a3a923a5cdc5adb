"""Every layer below the nodes imports without ROS (STYLE habit 1), and the layers depend one
way: a module imports only from its own layer and the layers below it
(docs/architecture.md)."""

import ast
import subprocess
import sys
from pathlib import Path

import formation_ilc

PACKAGE = Path(formation_ilc.__file__).parent
#: bottom to top; ``nodes`` (ROS) sits above ``recordings``, and ``cli`` above everything
LAYERS = ["system", "core", "config", "model", "store", "protocol", "recordings", "studies",
          "nodes", "cli"]
ROS_FREE = [layer for layer in LAYERS if layer != "nodes"]


def _modules(layer: str) -> list[str]:
    return sorted(f"formation_ilc.{layer}." + p.stem for p in (PACKAGE / layer).glob("*.py")
                  if p.stem not in ("__init__", "__main__"))


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


def _imported_layers(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "formation_ilc" and len(parts) > 1 and parts[1] in LAYERS:
                found.add(parts[1])
    return found


def test_layers_import_only_downwards():
    assert sorted(p.name for p in PACKAGE.iterdir()
                  if p.is_dir() and (p / "__init__.py").exists()) == sorted(LAYERS)
    upward = []
    for layer in LAYERS:
        for path in sorted((PACKAGE / layer).glob("*.py")):
            for other in _imported_layers(path):
                if LAYERS.index(other) > LAYERS.index(layer):
                    upward.append(f"{path.relative_to(PACKAGE)} imports formation_ilc.{other}")
    assert not upward, upward


def test_no_relative_import_reaches_outside_its_layer():
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                assert node.level <= 1, f"{path}: from {'.' * node.level}{node.module}"
