"""formation_ilc.store.atomic: the one writer of every file a crash must leave whole."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from formation_ilc.store.atomic import atomic_open, atomic_write_text


def test_replaces_the_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "state.json"
    atomic_write_text(path, "old\n")
    atomic_write_text(path, "new\n")
    assert path.read_text() == "new\n"
    assert os.listdir(path.parent) == ["state.json"]


def test_an_exception_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    path = tmp_path / "memory.npz"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError), atomic_open(path) as fh:
        fh.write(b"half of the new")
        raise RuntimeError("crash while writing")
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["memory.npz"]


def test_the_temporary_is_invisible_to_globs_for_the_final_suffix(tmp_path):
    with atomic_open(tmp_path / "a.json", "w") as fh:
        fh.write("{}")
        assert list(tmp_path.glob("*.json")) == []
        assert len(list(tmp_path.iterdir())) == 1  # the temporary exists meanwhile
    assert [p.name for p in tmp_path.glob("*.json")] == ["a.json"]


def test_a_killed_writer_leaves_the_old_version_whole(tmp_path):
    """SIGKILL in the middle of a write: no handler runs, and the old file is still whole."""
    path = tmp_path / "leader.json"
    atomic_write_text(path, '{"committed": 3}\n')
    code = ("import os, signal, sys\n"
            "from formation_ilc.store.atomic import atomic_open\n"
            f"with atomic_open({str(path)!r}, 'w') as fh:\n"
            "    fh.write('{\"committed\": ')\n"
            "    fh.flush()\n"
            "    os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
    assert proc.returncode == -9, proc.stderr
    assert path.read_text() == '{"committed": 3}\n'


def test_read_modes_are_refused(tmp_path):
    with pytest.raises(ValueError, match="no 'w'"), atomic_open(tmp_path / "x", "rb"):
        pass
