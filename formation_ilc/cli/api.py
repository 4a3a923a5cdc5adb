"""The Python entry point: ``formation_ilc.run(...)`` runs a scenario and returns its metrics.

On the batch simulator (``stack=False``, the default) in this process, as
``formation-ilc simulate`` does; on the distributed ROS 2 stack (``stack=True``) as
``formation-ilc launch`` does, in child processes (the launcher owns its signals, its
environment and its processes): its console lines go to this process's stdout, and its
outputs to ``out`` (a new temporary folder when none is given).

    import formation_ilc

    r = formation_ilc.run("paper-triangle3", trials=20)
    print(r["max_position_error"][-1])    # the last trial's largest position error [m]
    r = formation_ilc.run("paper-triangle3", trials=3, stack=True)   # real ROS 2 nodes
"""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.metrics import METRIC_COLUMNS

__all__ = ["run", "RunResult", "RunFailed"]


class RunFailed(RuntimeError):
    """A stack run that did not finish with status 0 (``status``: the launcher's exit
    status, ``formation-ilc launch --help``); its outputs so far are in ``out``."""

    def __init__(self, status: int, out: Path):
        super().__init__(f"formation-ilc launch ended with status {status}; see {out}")
        self.status, self.out = status, out


@dataclass(frozen=True)
class RunResult:
    """A run's metrics: one row per trial (trial 0 first), columns ``METRIC_COLUMNS``
    (metres, radians; ``metrics.csv``'s). ``r["max_position_error"]`` is a column;
    ``out`` the folder of the run's files (None: a batch run without ``out``)."""

    metrics: NDArray[np.float64]
    out: Path | None = None
    columns: tuple[str, ...] = METRIC_COLUMNS

    def __getitem__(self, column: str) -> NDArray[np.float64]:
        try:
            return self.metrics[:, self.columns.index(column)]
        except ValueError:
            raise KeyError(f"{column!r}: no such column (columns: "
                           f"{', '.join(self.columns)})") from None

    @property
    def trials(self) -> int:
        return int(self.metrics.shape[0])


def run(scenario: Any = "paper-triangle3", trials: int | None = None, *,
        stack: bool = False, seed: int | None = None, noise: bool = True,
        delay: bool = True, law: int | None = None, memory: str | None = None,
        out: str | Path | None = None, options: Sequence[str] = ()) -> RunResult:
    """Run ``scenario`` (a built-in name, a YAML file, or on the batch simulator a
    ``Scenario``) for ``trials`` trials (default: the scenario's) and return its metrics.

    seed, noise, delay, law, memory : as ``simulate`` / ``launch``'s options of the same
    names. out : a folder for the run's files (the batch side writes metrics.csv there).
    options : more ``formation-ilc launch`` options for a stack run (e.g.
    ``["--plant", "physics"]``). Bad input raises ``ScenarioError`` (batch) or
    ``RunFailed`` with status 2 (stack), with the command's one-line error on stderr.
    """
    if stack:
        return _run_stack(scenario, trials, seed, noise, delay, law, memory, out, options)
    if options:
        raise ValueError("options: only for a stack run (stack=True)")
    return _run_batch(scenario, trials, seed, noise, delay, law, memory, out)


def _run_batch(scenario: Any, trials: int | None, seed: int | None, noise: bool,
               delay: bool, law: int | None, memory: str | None,
               out: str | Path | None) -> RunResult:
    from formation_ilc.config.scenario import Scenario, load_scenario
    from formation_ilc.core._jit import cache_dir
    from formation_ilc.core.metrics import write_metrics
    from formation_ilc.model.simulate import simulate
    from formation_ilc.system.compiling import compile_notes

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    sc = sc.with_options(law=law, memory=memory, noise=noise, delay=delay, seed=seed,
                         trials=trials)
    with compile_notes(where=cache_dir()):
        res = simulate(sc)
    folder = None
    if out is not None:
        folder = Path(out)
        folder.mkdir(parents=True, exist_ok=True)
        write_metrics(folder / "metrics.csv", res.metrics)
    return RunResult(res.metrics, folder)


def _run_stack(scenario: Any, trials: int | None, seed: int | None, noise: bool,
               delay: bool, law: int | None, memory: str | None, out: str | Path | None,
               options: Sequence[str]) -> RunResult:
    from formation_ilc.core.metrics import read_metrics

    if not isinstance(scenario, (str, Path)):
        raise TypeError("scenario: a stack run takes a built-in name or a YAML file")
    folder = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="formation-ilc-"))
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", str(scenario), "--out",
            str(folder)]
    for flag, value in (("--trials", trials), ("--seed", seed), ("--law", law),
                        ("--memory", memory)):
        if value is not None:
            argv += [flag, str(value)]
    argv += ["--no-noise"] * (not noise) + ["--no-delay"] * (not delay) + list(options)
    sys.stdout.flush()
    proc = subprocess.Popen(argv)
    try:
        status = proc.wait()
    except KeyboardInterrupt:
        # a terminal's Ctrl-C reached the launcher too; else (a notebook's interrupt) it is
        # passed on: either way the launcher stops its nodes itself, and is waited for
        try:
            proc.wait(2.0)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)
        proc.wait()
        raise
    if status != 0:
        raise RunFailed(status, folder)
    return RunResult(read_metrics(folder / "metrics.csv"), folder)
