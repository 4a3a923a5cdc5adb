"""A sweep on a real Dask cluster (scheduler and two workers as separate processes on
127.0.0.1) gives the same table, byte for byte, as the local pool."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from formation_ilc.studies.sweep import load_spec, read_table, run_sweep

pytestmark = [pytest.mark.multiprocess, pytest.mark.slow]

SPEC = """\
scenario: paper-triangle3
trials: 30
seeds: [1, 2]
floor_window: 10
grid:
  law.gain: [0.08, 0.4]
  law.kind: [9, 22]
  delay: [paper, none]
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in reversed(procs):
        if p.poll() is None:
            p.terminate()
    for p in reversed(procs):
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


def test_dask_cluster_table_equals_local_pool(tmp_path):
    dask = Path(sys.executable).with_name("dask")
    if not dask.exists():
        pytest.fail("the dask CLI is missing: pip install -e '.[cluster]'")
    spec_path = tmp_path / "spec.yaml"
    spec_path.write_text(SPEC)
    spec = load_spec(spec_path)
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ)  # the workers' BLAS as it comes: tasks limit it themselves
    logs = tmp_path / "logs"
    logs.mkdir()
    procs: list[subprocess.Popen] = []
    try:
        procs.append(subprocess.Popen(
            [str(dask), "scheduler", "--host", "127.0.0.1", "--port", str(port),
             "--no-dashboard"], stdout=(logs / "scheduler.log").open("w"),
            stderr=subprocess.STDOUT, env=env, cwd=tmp_path))
        for i in range(2):
            procs.append(subprocess.Popen(
                [str(dask), "worker", addr, "--host", "127.0.0.1", "--nthreads", "1",
                 "--nworkers", "1", "--no-dashboard", "--name", f"w{i}"],
                stdout=(logs / f"worker{i}.log").open("w"), stderr=subprocess.STDOUT,
                env=env, cwd=tmp_path))
        from distributed import Client

        deadline = time.monotonic() + 120
        with Client(addr, timeout=60) as client:
            while len(client.scheduler_info()["workers"]) < 2:
                assert time.monotonic() < deadline, "the two Dask workers did not connect"
                assert all(p.poll() is None for p in procs), "a Dask process died"
                time.sleep(0.2)
            hosts = {w.split("://")[1].split(":")[0] for w in client.scheduler_info()["workers"]}
            assert hosts == {"127.0.0.1"}
        rows_seen: list[str] = []
        on_dask = run_sweep(spec, tmp_path / "dask", scheduler=addr, progress=False,
                            on_row=lambda r: rows_seen.append(r["id"]))
        local = run_sweep(spec, tmp_path / "local", workers=2, progress=False)
    finally:
        _stop(procs)
        for p in procs:
            assert p.poll() is not None
    assert len(rows_seen) == len(spec.sim_tasks()) + len(spec.check_tasks())
    assert on_dask.read_bytes() == local.read_bytes()
    rows = read_table(on_dask)
    assert len(rows) == 16 and all(r["cond20"] for r in rows)
    shutil.rmtree(tmp_path / "logs", ignore_errors=True)
