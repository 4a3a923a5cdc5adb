"""Parameter studies: a spec file expands to points, each point is simulated and reduced to a
row, rows go to one table. Runs on a local process pool or a Dask cluster, resumably.

Spec (YAML), validated as strictly as a scenario file::

    scenario: paper-hexagon6       # built-in name, or a scenario file (relative to the spec)
    trials: 300                    # trials per point
    seeds: [1, 2, 3]               # or {first: 1, count: 5}
    position_level: 1.0            # [m]   trials_to_position: first trial staying below
    heading_level: 0.1             # [rad] trials_to_heading: the same for heading
    floor_window: 100              # floor = median of the last N trials
    check: true                    # condition (20) and the lifted heading map per config
    grid:                          # every combination (exactly one of grid / random)
      law.gain: [0.08, 0.8]
      law.kind: [9, 22]
    random:                        # or: draws
      count: 20
      seed: 0
      fields:
        law.gain: {log_uniform: [0.05, 2.0]}
        law.gain_prime: {uniform: [0.05, 2.0]}
        law.kind: {choice: [9, 22, 23]}

Resumability: every finished point is written at once to ``OUT/points/ID.json`` (written to a
temporary file, fsync'd, renamed: a point is either complete or absent). ID is a hash of the
scenario text, the changed fields, the trials and the seed, so a restarted sweep skips the
points it finds and recomputes nothing. ``OUT/results.csv`` is rebuilt from the point files in
point order, so it does not depend on the order in which points finished, nor on where they
ran.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from formation_ilc.config.scenario import Scenario, builtin_scenarios, load_scenario
from formation_ilc.config.yamlfields import (
    Fields,
    ScenarioError,
    parse_yaml,
    read_text_file,
    show,
)
from formation_ilc.store.atomic import atomic_open
from formation_ilc.studies.study import (
    CHECK_COLUMNS,
    FIELDS,
    SIM_COLUMNS,
    apply_fields,
    config_id,
    point_id,
    run_check_point,
    run_sim_point,
    scenario_data,
)
from formation_ilc.system.progress import Progress

__all__ = ["SweepSpec", "load_spec", "spec_from_text", "run_sweep", "plot_table", "map_tasks",
           "close_pools", "TABLE_COLUMNS", "read_table"]

#: results.csv columns: point index, ids, seed, one column per varied field, the row
TABLE_HEAD = ("index", "point", "config", "seed")
TABLE_COLUMNS = TABLE_HEAD + SIM_COLUMNS + CHECK_COLUMNS


@dataclass(frozen=True)
class SweepSpec:
    """A validated study: the base scenario's text, the configurations and the seeds."""

    source: str
    scenario_text: str
    trials: int
    seeds: tuple[int, ...]
    position_level: float
    heading_level: float
    floor_window: int
    check: bool
    fields: tuple[str, ...]
    configs: tuple[dict[str, Any], ...]

    def sim_tasks(self) -> list[dict[str, Any]]:
        """One task per (configuration, seed), in table order."""
        out = []
        for ci, cfg in enumerate(self.configs):
            for seed in self.seeds:
                out.append({"id": point_id(self.scenario_text, cfg, self.trials, seed),
                            "config": config_id(self.scenario_text, cfg, self.trials),
                            "scenario": self.scenario_text, "fields": cfg, "seed": seed,
                            "trials": self.trials, "position_level": self.position_level,
                            "heading_level": self.heading_level,
                            "floor_window": self.floor_window,
                            "source": f"{self.source}: point {ci}", "index": ci})
        return out

    def check_tasks(self) -> list[dict[str, Any]]:
        if not self.check:
            return []
        return [{"id": "check-" + config_id(self.scenario_text, cfg, self.trials),
                 "scenario": self.scenario_text, "fields": cfg, "trials": self.trials,
                 "source": f"{self.source}: point {ci}"}
                for ci, cfg in enumerate(self.configs)]


#: most points (configurations x seeds) a spec may expand to: its table is built in memory
MAX_POINTS = 1_000_000


def _value_list(f: Fields, key: str, v: Any) -> list[Any]:
    if not isinstance(v, list) or not v:
        raise f.fail(key, f"expected a non-empty list of values, got {show(v)}")
    return v


def _draw(f: Fields, key: str, dist: Any, rng: np.random.Generator, count: int) -> list[Any]:
    df = Fields(dist, f"{f.path}.{key}", f.src)
    kinds = [k for k in ("uniform", "log_uniform", "choice") if k in dist]
    if len(kinds) != 1:
        raise df.fail(None, "give exactly one of uniform: [lo, hi], log_uniform: [lo, hi], "
                            "choice: [values]")
    kind = kinds[0]
    if kind == "choice":
        vals = _value_list(df, "choice", df.get("choice"))
        idx = rng.integers(0, len(vals), count)
        df.finish()
        return [vals[i] for i in idx]
    lo, hi = df.numbers(kind, 2)
    if not lo < hi:
        raise df.fail(kind, f"needs lo < hi, got [{lo}, {hi}]")
    if kind == "log_uniform":
        if lo <= 0:
            raise df.fail(kind, f"bounds must be > 0, got [{lo}, {hi}]")
        vals_f = np.exp(rng.uniform(math.log(lo), math.log(hi), count))
    else:
        vals_f = rng.uniform(lo, hi, count)
    df.finish()
    return [float(x) for x in vals_f]


def spec_from_text(text: str, source: str = "<spec>", base_dir: Path | None = None
                   ) -> SweepSpec:
    """Parse and validate a sweep spec; ScenarioError names the file, the field and why."""
    data = parse_yaml(text, source)
    top = Fields(data, "", source)
    sc, path = _spec_scenario(top, base_dir)
    scenario_text = _self_contained(sc.text, sc.source, path.parent)
    trials = top.integer("trials", sc.trials, minimum=1)
    seeds = _seeds(top, sc.seed)
    pos_level = top.number("position_level", 1.0, positive=True)
    head_level = top.number("heading_level", 0.1, positive=True, angle=True)
    floor_window = top.integer("floor_window", min(100, trials), minimum=1)
    if floor_window > trials:
        raise top.fail("floor_window", f"must be <= trials ({trials}), got {floor_window}")
    check = top.get("check", True)
    if not isinstance(check, bool):
        raise top.fail("check", f"expected true or false, got {check!r}")
    has_grid, has_random = "grid" in data, "random" in data
    if has_grid == has_random:
        raise ScenarioError(f"{source}: top level: give exactly one of 'grid' (every "
                            f"combination) or 'random' (draws)")
    fields, configs = _grid(top, len(seeds)) if has_grid else _random(top, len(seeds))
    top.finish()
    _check_points(scenario_text, configs, source, "grid" if has_grid else "random")
    return SweepSpec(source=source, scenario_text=scenario_text, trials=trials, seeds=seeds,
                     position_level=pos_level, heading_level=head_level,
                     floor_window=floor_window, check=check, fields=tuple(fields),
                     configs=tuple(configs))


def _spec_scenario(top: Fields, base_dir: Path | None) -> tuple[Scenario, Path]:
    """A sweep spec's scenario (a built-in, or a file beside the spec) and its path."""
    scen = top.string("scenario")
    path = Path(scen) if base_dir is None or Path(scen).is_absolute() else base_dir / scen
    if scen in builtin_scenarios() and not path.exists():
        sc = load_scenario(scen)
    elif path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise top.fail("scenario", f"no such file {path}")
        sc = load_scenario(path)
    else:
        raise top.fail("scenario", f"{scen!r} is neither a file nor a built-in scenario "
                                   f"({', '.join(builtin_scenarios())})")
    return sc, path


def _seeds(top: Fields, default: int) -> tuple[int, ...]:
    """A sweep spec's seeds: a list, or {first, count}."""
    seeds_raw = top.get("seeds", [default])
    if isinstance(seeds_raw, dict):
        sf = top.sub("seeds")
        first = sf.integer("first", 1, minimum=0)
        count = sf.integer("count", minimum=1)
        if count > MAX_POINTS:
            raise sf.fail("count", f"at most {MAX_POINTS} seeds, got {count}")
        sf.finish()
        seeds = tuple(range(first, first + count))
    elif isinstance(seeds_raw, list) and seeds_raw:
        for i, s in enumerate(seeds_raw):
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise top.fail(f"seeds[{i}]", f"expected an integer >= 0, got {s!r}")
        if len(set(seeds_raw)) != len(seeds_raw):
            raise top.fail("seeds", "a seed is listed twice")
        seeds = tuple(seeds_raw)
    else:
        raise top.fail("seeds", f"expected a list of seeds or {{first, count}}, got "
                                f"{show(seeds_raw)}")
    return seeds


def _grid(top: Fields, n_seeds: int) -> tuple[list[str], list[dict[str, Any]]]:
    """The fields a grid varies and its points (every combination)."""
    fields: list[str] = []
    columns: list[list[Any]] = []
    gf = top.sub("grid")
    for key in list(gf.data):
        if key not in FIELDS:
            raise gf.fail(str(key), f"not a field a sweep can vary (known: "
                                    f"{', '.join(FIELDS)})")
        fields.append(key)
        columns.append(_value_list(gf, key, gf.get(key)))
    gf.finish()
    if not fields:
        raise top.fail("grid", "vary at least one field")
    size = math.prod(len(c) for c in columns) * n_seeds
    if size > MAX_POINTS:
        raise top.fail("grid", f"{size} points (every combination x {n_seeds} seeds) "
                               f"is more than the {MAX_POINTS} a sweep may have")
    configs = [dict(zip(fields, combo, strict=True)) for combo in itertools.product(*columns)]
    return fields, configs


def _random(top: Fields, n_seeds: int) -> tuple[list[str], list[dict[str, Any]]]:
    """The fields random draws vary and its points (the draws)."""
    fields: list[str] = []
    rf = top.sub("random")
    count = rf.integer("count", minimum=1)
    if count * n_seeds > MAX_POINTS:
        raise rf.fail("count", f"{count} draws x {n_seeds} seeds is more than the "
                               f"{MAX_POINTS} points a sweep may have")
    rng = np.random.default_rng(rf.integer("seed", 0, minimum=0))
    ff = rf.sub("fields")
    draws = []
    for key in list(ff.data):
        if key not in FIELDS:
            raise ff.fail(str(key), f"not a field a sweep can vary (known: "
                                    f"{', '.join(FIELDS)})")
        fields.append(key)
        draws.append(_draw(ff, key, ff.get(key), rng, count))
    ff.finish()
    rf.finish()
    if not fields:
        raise rf.fail("fields", "draw at least one field")
    configs = [dict(zip(fields, vals, strict=True)) for vals in zip(*draws, strict=True)]
    return fields, configs


def _check_points(scenario_text: str, configs: list[dict[str, Any]], source: str,
                  where: str) -> None:
    """Every configuration must be a valid scenario: ScenarioError says which point and
    which field is not."""
    for ci, cfg in enumerate(configs):
        try:
            apply_fields(scenario_text, cfg, f"{source}: {where} point {ci} "
                                             f"({_describe(cfg)}) -> scenario")
        except ScenarioError:
            raise
        except ValueError as exc:
            raise ScenarioError(f"{source}: {where} point {ci} ({_describe(cfg)}): {exc}"
                                ) from None


def _self_contained(text: str, source: str, base: Path) -> str:
    """The scenario text with a ``reference.file`` inlined as points, so that workers need
    no shared disk."""
    data = parse_yaml(text, source)  # as the scenario loader reads it (1e-3 is a number)
    ref = data.get("reference") if isinstance(data, dict) else None
    if isinstance(ref, dict) and ref.get("kind") == "samples" and "file" in ref:
        pts = np.loadtxt(base / ref["file"], delimiter=",", ndmin=2, comments="#")[:, :2]
        ref = dict(ref)
        del ref["file"]
        ref["points"] = pts.tolist()
        data["reference"] = ref
        return yaml.safe_dump(data, sort_keys=False)
    return text


def _describe(cfg: dict[str, Any]) -> str:
    return ", ".join(f"{k}={json.dumps(v)}" for k, v in cfg.items())


def load_spec(path: str | Path) -> SweepSpec:
    p = Path(path)
    return spec_from_text(read_text_file(p, what="a sweep spec"), str(p), p.parent)


# --------------------------------------------------------------------------- storage

def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write JSON so that ``path`` is either complete or absent, also after a power cut."""
    with atomic_open(path, "w") as fh:
        json.dump(data, fh, sort_keys=True)


def _read_done(folder: Path) -> dict[str, dict[str, Any]]:
    done = {}
    for p in folder.glob("*.json"):
        try:
            row = json.loads(p.read_text())
        except (OSError, ValueError):
            continue  # cannot happen with atomic writes; recompute if it does
        done[p.stem] = row
    return done


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return str(int(v))
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.17g}"
    if isinstance(v, (int, str)):
        return str(v)
    return json.dumps(v, sort_keys=True, separators=(",", ":"))


def write_table(spec: SweepSpec, out: Path, rows: dict[str, dict[str, Any]]) -> Path:
    """results.csv in point order: TABLE_HEAD, the varied fields, SIM_COLUMNS, CHECK_COLUMNS.

    Numbers with 17 significant digits (float64 round-trips exactly); an empty cell means
    never (trials_to_*) or not computed.
    """
    path = out / "results.csv"
    with atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TABLE_HEAD + spec.fields + SIM_COLUMNS + CHECK_COLUMNS)
        for task in spec.sim_tasks():
            row = rows[task["id"]]
            chk = rows.get("check-" + task["config"], {})
            w.writerow([_cell(task["index"]), task["id"], task["config"], _cell(task["seed"])]
                       + [_cell(task["fields"][f]) for f in spec.fields]
                       + [_cell(row.get(c)) for c in SIM_COLUMNS]
                       + [_cell(chk.get(c)) for c in CHECK_COLUMNS])
    return path


def read_table(path: str | Path) -> list[dict[str, str]]:
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------------------- execution

def points_progress(total: int, already: int, label: str) -> Progress:
    """Progress of a study on stderr: points done, expected time left from this session's
    rate (a bar on a terminal, a line every 5 s in a log)."""
    return Progress(total, label, "points", initial=already, interval=0.2, every=5.0)


def _run_task(task: dict[str, Any]) -> dict[str, Any]:
    return run_check_point(task) if task["id"].startswith("check-") else run_sim_point(task)


def _run_chunk(tasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """What a worker process (local or Dask) runs: a few tasks, their rows in order."""
    return [_run_task(t) for t in tasks]


_LIMITS: list[Any] = []


def _worker_init() -> None:
    """A local pool's worker: BLAS and OpenMP on one thread. The worker processes are the
    parallelism; a library's own threads would compete with them for the cores. (A Dask
    worker is not ours to change: start it with --nthreads 1; check tasks limit BLAS
    themselves.)"""
    from threadpoolctl import threadpool_limits

    _LIMITS.append(threadpool_limits(limits=1))  # kept: the limit lasts while it lives


#: a task sent to a worker holds points up to about this many robot-samples (about 0.1 s on
#: one core), so that the cost of a task to the pool or the cluster stays small against its
#: work when points are small; never fewer than CHUNKS_PER_WORKER tasks per worker, for an
#: even finish
CHUNK_ROBOT_SAMPLES = 1_000_000
CHUNKS_PER_WORKER = 8


def _robot_samples(task: dict[str, Any]) -> float:
    """A sim task's size (robots x samples x trials); inf for a check task or when unknown."""
    if task["id"].startswith("check-"):
        return math.inf
    try:
        data = scenario_data(task["scenario"])
        return float(int(data["robots"]) * int(data["samples"]) * int(task["trials"]))
    except (KeyError, TypeError, ValueError):
        return math.inf


def chunk_tasks(tasks: list[dict[str, Any]], workers: int) -> list[list[dict[str, Any]]]:
    """Consecutive tasks grouped into chunks (one per worker task), in order: a check task
    alone, sim points together up to CHUNK_ROBOT_SAMPLES and at most len / (workers x
    CHUNKS_PER_WORKER) points per chunk."""
    most = max(1, math.ceil(len(tasks) / (max(1, workers) * CHUNKS_PER_WORKER)))
    chunks: list[list[dict[str, Any]]] = []
    cur: list[dict[str, Any]] = []
    size = 0.0
    for t in tasks:
        c = _robot_samples(t)
        if cur and (len(cur) >= most or size + c > CHUNK_ROBOT_SAMPLES):
            chunks.append(cur)
            cur, size = [], 0.0
        cur.append(t)
        size += c
    if cur:
        chunks.append(cur)
    return chunks


_POOLS: dict[int, Any] = {}


def _pool(workers: int) -> Any:
    """A process pool of ``workers`` processes, started once and reused by later calls (tune
    maps several batches; starting a process costs imports and loading the compiled
    kernels). Shut down at interpreter exit, or at once after an error."""
    import atexit
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ex = _POOLS.get(workers)
    if ex is None:
        ex = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                 initializer=_worker_init)
        _POOLS[workers] = ex
        atexit.register(_shutdown_pool, workers)
    return ex


def _shutdown_pool(workers: int) -> None:
    ex = _POOLS.pop(workers, None)
    if ex is not None:
        ex.shutdown(wait=True, cancel_futures=True)


def close_pools() -> None:
    """Stop the local worker processes that map_tasks started."""
    for w in list(_POOLS):
        _shutdown_pool(w)


def _local_map(tasks: list[dict[str, Any]], workers: int) -> Iterable[dict[str, Any]]:
    from concurrent.futures import as_completed

    ex = _pool(workers)
    futs = [ex.submit(_run_chunk, c) for c in chunk_tasks(tasks, workers)]
    try:
        for f in as_completed(futs):
            yield from f.result()
    except BaseException:
        for f in futs:
            f.cancel()
        _shutdown_pool(workers)
        raise


def _dask_map(tasks: list[dict[str, Any]], address: str) -> Iterable[dict[str, Any]]:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ScenarioError("--scheduler needs Dask: pip install -e '.[cluster]'") from None
    with Client(address, timeout=30) as client:
        workers = sum(client.nthreads().values())
        futs = client.map(_run_chunk, chunk_tasks(tasks, workers), pure=False)
        try:
            for f in as_completed(futs):
                yield from f.result()
        except BaseException:
            client.cancel(futs)
            raise


def map_tasks(tasks: list[dict[str, Any]], workers: int | None = None,
              scheduler: str | None = None) -> Iterable[dict[str, Any]]:
    """Run study tasks (sim or check), yielding rows as they finish, in any order: on a
    Dask cluster if ``scheduler`` is given, else on ``workers`` local processes (default:
    every core; 1 = in this process)."""
    if not tasks:
        return iter(())
    if scheduler is not None:
        return _dask_map(tasks, scheduler)
    if (workers or os.cpu_count() or 1) == 1:
        return map(_run_task, tasks)
    return _local_map(tasks, workers or os.cpu_count() or 1)


def run_sweep(spec: SweepSpec, out: Path, workers: int | None = None,
              scheduler: str | None = None, progress: bool = True,
              on_row: Callable[[dict[str, Any]], None] | None = None,
              keep_pool: bool = False) -> Path:
    """Run every point not yet in ``out/points`` and write ``out/results.csv``.

    workers : local processes (default: every core); scheduler : a Dask scheduler address
    ("tcp://127.0.0.1:8786"); the same tasks and the same function run there.
    keep_pool : leave the local processes running for the next call (else stopped).
    Returns the table's path.
    """
    out.mkdir(parents=True, exist_ok=True)
    folder = out / "points"
    folder.mkdir(exist_ok=True)
    (out / "spec.json").write_text(json.dumps(
        {"source": spec.source, "trials": spec.trials, "seeds": list(spec.seeds),
         "fields": list(spec.fields), "configs": list(spec.configs)}, indent=1) + "\n")
    done = _read_done(folder)
    tasks = spec.check_tasks() + spec.sim_tasks()
    todo = [t for t in tasks if t["id"] not in done]
    bar = points_progress(len(tasks), len(tasks) - len(todo), "sweep") if progress else None
    writer = _PointWriter(folder)
    finished = False
    try:
        for row in map_tasks(todo, workers, scheduler):
            writer.put(row)
            done[row["id"]] = row
            if bar is not None:
                bar.step()
            if on_row is not None:
                on_row(row)
        finished = True
    finally:
        if bar is not None:
            bar.close()  # an interrupted sweep's bar keeps its line, what follows goes below
        try:
            writer.close()  # every point finished so far reaches the disk, Ctrl-C or not
        except Exception:
            if finished:
                raise  # else the error in flight says more
        finally:
            if not keep_pool:
                close_pools()
    return write_table(spec, out, done)


class _PointWriter:
    """Writes finished points with ``_write_atomic`` on a thread of its own: the fsyncs (a
    few ms each) overlap the next point's computation instead of adding to it. A write
    error is raised by the next ``put`` or by ``close``."""

    def __init__(self, folder: Path):
        import queue
        import threading

        self.folder = folder
        self.queue: queue.SimpleQueue[dict[str, Any] | None] = queue.SimpleQueue()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="sweep-writer", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while (row := self.queue.get()) is not None:
            if self.error is None:
                try:
                    _write_atomic(self.folder / f"{row['id']}.json", row)
                except BaseException as exc:  # handed to the caller by put or close
                    self.error = exc

    def put(self, row: dict[str, Any]) -> None:
        if self.error is not None:
            raise self.error
        self.queue.put(row)

    def close(self) -> None:
        """Wait until every row put has been written."""
        self.queue.put(None)
        self.thread.join()
        if self.error is not None:
            raise self.error


# --------------------------------------------------------------------------- plots

def _numeric(v: str) -> float | None:
    try:
        return float(v)
    except ValueError:
        return None


def plot_table(spec: SweepSpec, table: Path, out: Path,
               metric: str = "trials_to_position") -> list[Path]:
    """Heat map of ``metric`` (median over seeds) over the first two varied scalar fields,
    and lines of it against the first field, one line per value of the second."""
    from formation_ilc.recordings.plots import _plt

    rows = read_table(table)
    scalar = [f for f in spec.fields
              if all(_numeric(r[f]) is not None for r in rows) and len({r[f] for r in rows}) > 1]
    cat = [f for f in spec.fields if f not in scalar and len({r[f] for r in rows}) > 1]
    if not scalar:
        return []
    x = scalar[0]
    y = scalar[1] if len(scalar) > 1 else (cat[0] if cat else None)
    plt = _plt()
    paths = []

    def med(sel: list[dict[str, str]]) -> float:
        vals = [float(r[metric]) if r[metric] != "" else np.nan for r in sel]
        return float(np.median(vals)) if vals else np.nan

    xs = sorted({float(r[x]) for r in rows})
    ys = sorted({r[y] for r in rows}, key=lambda v: (_numeric(v) is None, _numeric(v) or 0, v)
                ) if y else [""]
    grid = np.array([[med([r for r in rows if float(r[x]) == xv and (not y or r[y] == yv)])
                      for xv in xs] for yv in ys])
    fig, ax = plt.subplots(figsize=(7, 5))
    im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
    ax.set_xticks(range(len(xs)), [f"{v:.3g}" for v in xs])
    ax.set_yticks(range(len(ys)), [f"{float(v):.3g}" if _numeric(v) is not None else v
                                   for v in ys])
    ax.set_xlabel(x)
    ax.set_ylabel(y or "")
    for (i, j), v in np.ndenumerate(grid):
        ax.text(j, i, "never" if np.isnan(v) else f"{v:.3g}", ha="center", va="center",
                color="k" if np.isnan(v) else "w", fontsize=8)
    fig.colorbar(im, ax=ax, label=f"{metric} (median over seeds; blank = never)")
    ax.set_title(f"{Path(spec.source).name}: {metric}")
    fig.tight_layout()
    paths.append(out / f"heatmap_{metric}.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for yv, line in zip(ys, grid, strict=True):
        lab = f"{float(yv):.3g}" if y and _numeric(yv) is not None else yv
        ax.plot(xs, line, "o-", label=f"{y} = {lab}" if y else metric)
    ax.set_xlabel(x)
    ax.set_ylabel(f"{metric} (median over seeds)")
    ax.set_xscale("log" if min(xs) > 0 else "linear")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    paths.append(out / f"lines_{metric}.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths
