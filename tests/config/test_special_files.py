"""A scenario path that is no regular file (a FIFO, a device) is refused at once with one
line and status 2; before, a FIFO made ``launch`` wait forever for a writer."""

from __future__ import annotations

import os
import subprocess
import sys


def test_a_fifo_or_a_device_as_scenario_is_one_line_at_once(tmp_path):
    fifo = tmp_path / "scenario.yaml"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "a FIFO"), ("/dev/zero", "a device")):
        # a child with a deadline: a reader that waits for the FIFO's writer fails the
        # test instead of hanging it
        res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", str(path),
                              "--out", str(tmp_path / "out")], capture_output=True,
                             text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        assert res.stderr == f"error: {path}: {kind}, not a scenario file (a regular file is " \
                             f"needed)\n"
