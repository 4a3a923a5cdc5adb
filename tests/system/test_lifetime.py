"""A process that starts to stop ends within its bound, and knows when its launcher is gone."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

from formation_ilc.system.lifetime import PARENT_ENV


def _run(code: str, env: dict[str, str] | None = None, timeout: float = 30.0
         ) -> tuple[subprocess.CompletedProcess[str], float]:
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                         text=True, timeout=timeout, env=env)
    return res, time.monotonic() - t0


def test_a_stop_that_hangs_is_ended_by_its_bound():
    res, _ = _run("""
        import time
        from formation_ilc.system.lifetime import bound_the_stop
        bound_the_stop(0.5)
        bound_the_stop(60.0)  # a second call does not push the bound back
        time.sleep(20)  # a teardown that never returns
        print("not reached")
    """)
    assert res.returncode == -signal.SIGALRM, res
    assert "not reached" not in res.stdout


GONE = "from formation_ilc.system.lifetime import parent_gone; print(parent_gone())"


def test_parent_gone_follows_the_launcher_pid():
    env = dict(os.environ)
    env[PARENT_ENV] = str(os.getpid())  # this test is the child's parent
    res, _ = _run(GONE, env)
    assert res.stdout.strip() == "False", res
    env[PARENT_ENV] = "1"  # not the parent: as after the launcher died
    res, _ = _run(GONE, env)
    assert res.stdout.strip() == "True", res
    env.pop(PARENT_ENV)  # started by hand: no launcher to follow
    res, _ = _run(GONE, env)
    assert res.stdout.strip() == "False", res
