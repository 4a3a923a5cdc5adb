"""A run's files are its user's alone while it lives (formation_ilc.system.private)."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time

from formation_ilc.system.private import private


def mode(p) -> int:
    return stat.S_IMODE(p.stat().st_mode)


def test_files_made_in_the_run_are_private_then_get_the_users_modes_back(tmp_path):
    out, rec = tmp_path / "run", tmp_path / "rec" / "run.mcap"
    out.mkdir()
    rec.parent.mkdir()
    (out / "before.txt").write_text("x")
    (out / "before.txt").chmod(0o640)
    time.sleep(0.05)
    old = os.umask(0o022)
    try:
        with private([out, rec]):
            # a child process (a node) makes its files with the run's umask
            subprocess.run([sys.executable, "-c",
                            f"open({str(rec)!r}, 'w').write('key'); "
                            f"import os; os.mkdir({str(out / 'state')!r}); "
                            f"open({str(out / 'state' / 'leader.json')!r}, 'w')"], check=True)
            assert mode(rec) == 0o600 and mode(out / "state") == 0o700
            assert mode(out / "state" / "leader.json") == 0o600
        assert os.umask(0o022) == 0o022  # the launcher's own umask is back
        assert mode(rec) == 0o644 and mode(out / "state") == 0o755
        assert mode(out / "state" / "leader.json") == 0o644
        assert mode(out / "before.txt") == 0o640  # what the run did not make: untouched
    finally:
        os.umask(old)
