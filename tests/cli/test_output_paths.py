"""Output files that are no files on a disk (a device, a FIFO, a file of /proc) are refused
while the arguments are parsed: one line, status 2, nothing created (formation_ilc.cli.options).
Before, ``launch --record /dev/full`` exited 0 and created ``/dev/full.part1.mcap``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from formation_ilc.cli.commands import main
from formation_ilc.cli.options import fs_type, special_path


@pytest.mark.parametrize("argv, path, why", [
    (["launch", "paper-triangle3", "--record"], "/dev/full", "is a character device"),
    (["launch", "paper-triangle3", "--record"], "/dev/full.part1.mcap", "is on devtmpfs"),
    (["simulate", "paper-triangle3", "--record"], "/proc/self/run.mcap", "is on proc"),
    (["mcap-repair", "x.mcap", "-o"], "/sys/kernel/fixed.mcap", "is on sysfs"),
])
def test_an_output_file_on_a_device_or_a_kernel_file_system_is_refused(capsys, argv, path,
                                                                        why):
    if fs_type(Path(path).parent) not in ("devtmpfs", "proc", "sysfs"):
        pytest.skip(f"{Path(path).parent} is no kernel file system here")
    with pytest.raises(SystemExit) as exc:
        main([*argv, path])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: {why}" in err, err
    assert not Path("/dev/full.part1.mcap").exists()


def test_a_fifo_is_no_output_file_and_a_shared_memory_file_is_one(tmp_path):
    fifo = tmp_path / "run.mcap"
    os.mkfifo(fifo)
    assert special_path(fifo, "file") == "is a FIFO, not a regular file"
    assert special_path(tmp_path / "other.mcap", "file") is None
    if Path("/dev/shm").is_dir() and fs_type(Path("/dev/shm")) == "tmpfs":
        assert special_path(Path("/dev/shm/run.mcap"), "file") is None  # memory, but a file
