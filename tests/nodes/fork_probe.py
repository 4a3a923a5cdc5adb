"""A node entry point for tests/nodes/test_forkserver.py: says (one JSON line) its
parent, its threads before and after rclpy joins the domain, its argv and an environment
variable, as a process forked by the fork server sees them."""

from __future__ import annotations

import json
import os
import sys


def _tasks() -> int:
    return len(os.listdir("/proc/self/task"))


def main() -> int:
    import rclpy

    before = _tasks()
    rclpy.init()
    node = rclpy.create_node("fork_probe")
    after = _tasks()
    print(json.dumps({"ppid": os.getppid(), "before": before, "after": after,
                      "argv": sys.argv[1:], "probe": os.environ.get("PROBE"),
                      "name": node.get_name(),
                      "cmdline": open("/proc/self/cmdline", "rb").read().replace(
                          b"\0", b" ").decode().strip()}), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 7


if __name__ == "__main__":
    sys.exit(main())
