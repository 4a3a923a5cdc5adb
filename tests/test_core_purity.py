"""The numerical core must import without ROS (STYLE habit 1)."""

import subprocess
import sys

CORE = ["topology", "kinematics", "trajectory", "delays", "law", "uncertainty", "scenario",
        "simulate", "checks", "plots", "cli", "study", "sweep", "tune", "netns", "schedule",
        "robotstate", "lifetime", "shm"]


def test_core_imports_without_rclpy():
    code = (
        "import sys\n"
        "for m in ('rclpy', 'rclpy.node', 'geometry_msgs', 'nav_msgs', 'std_msgs'):\n"
        "    sys.modules[m] = None\n"
        f"for m in {CORE!r}:\n"
        "    __import__('formation_ilc.' + m)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
