"""The benchmarks' stop of what they started (formation_ilc.system.proctree.terminate_all)."""

from __future__ import annotations

import signal
import subprocess
import sys

from formation_ilc.system.proctree import terminate_all

STUBBORN = ("import signal, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "print('ready', flush=True); time.sleep(60)")


def test_every_process_ends_and_one_that_ignores_sigterm_is_killed():
    polite = subprocess.Popen([sys.executable, "-c", "import time; print('ready', flush=True);"
                               " time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    stubborn = subprocess.Popen([sys.executable, "-c", STUBBORN], stdout=subprocess.PIPE,
                                text=True)
    try:
        for p in (polite, stubborn):  # their handlers are in place
            assert p.stdout is not None and p.stdout.readline() == "ready\n"
        terminate_all(iter([polite, stubborn]), 0.5)  # any iterable, taken once
        assert polite.returncode == -signal.SIGTERM
        assert stubborn.returncode == -signal.SIGKILL
    finally:
        for p in (polite, stubborn):
            if p.poll() is None:
                p.kill()
                p.wait()
            if p.stdout is not None:
                p.stdout.close()
