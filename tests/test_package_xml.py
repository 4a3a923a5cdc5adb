"""package.xml lists every ROS package the code imports (rosdep installs what it lists)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: imported only where the user brings it (a p2os2 driver's bridge, from p2os's workspace)
OPTIONAL = {"p2os_msgs"}


def _ros_imports() -> set[str]:
    found: set[str] = set()
    for folder in ("formation_ilc", "robot_sim", "virtual_leader", "msgs_schema", "launch"):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                         [node.module or ""] if isinstance(node, ast.ImportFrom)
                         and not node.level else [])
                for name in names:
                    top = name.split(".")[0]
                    if (top.endswith(("_msgs", "_srvs", "_interfaces"))
                            or top in ("rclpy", "launch", "launch_ros")):
                        found.add(top)
    return found


def test_package_xml_lists_every_ros_package_imported():
    listed = set(re.findall(r"<exec_depend>([\w-]+)</exec_depend>",
                            (ROOT / "package.xml").read_text()))
    imported = _ros_imports()
    assert {"rclpy", "lifecycle_msgs", "sensor_msgs", "launch_ros"} <= imported
    assert imported - OPTIONAL <= listed, sorted(imported - OPTIONAL - listed)
    assert "python3-cryptography" in listed  # the keystore's
