"""Scenario files (YAML): strict loading with errors that name the file, the field and why.

A scenario states every choice the paper leaves open: graph, formation frame, reference,
gains, memory reading, uncertainty and delay model. Built-in scenarios live in
``formation_ilc/config/scenarios`` and are named without their ``.yaml`` suffix.
"""

from __future__ import annotations

import json
import math
import warnings
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.yamlfields import (
    MAX_FILE_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_SIZE,
    Fields,
    ScenarioError,
    one_line,
    parse_yaml,
    printable,
    read_text_file,
    show,
)
from formation_ilc.core import trajectory as tr
from formation_ilc.core.delays import DelayModel
from formation_ilc.core.guards import format_bytes, memory_shortfall
from formation_ilc.core.law import HEADING_SOURCES, LAWS, MEMORY_MODES
from formation_ilc.core.topology import Graph
from formation_ilc.core.uncertainty import Harmonic, Uncertainty

__all__ = ["ScenarioError", "Scenario", "LawSettings", "load_scenario", "builtin_scenarios",
           "scenario_from_text", "scenario_from_data", "read_text_file", "parse_yaml",
           "load_bytes", "show", "MAX_FILE_BYTES", "MAX_YAML_DEPTH", "MAX_YAML_SIZE"]

#: where the built-in scenarios are
SCENARIO_PACKAGE = "formation_ilc.config.scenarios"
#: a scenario's name names the output folder: a file name, not a path
_MAX_NAME = 100


def builtin_scenarios() -> list[str]:
    files = resources.files(SCENARIO_PACKAGE).iterdir()
    return sorted(p.name[:-5] for p in files if p.name.endswith(".yaml"))


@dataclass(frozen=True)
class LawSettings:
    """Which law and memory reading, and the gains g (Gamma) and g' (Gamma') per robot."""

    kind: int = 9
    memory: str = "feedforward"
    gain: tuple[float, ...] = ()
    gain_prime: tuple[float, ...] = ()
    gain_heading: str = "measured"


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    dt: float
    samples: int
    trials: int
    seed: int
    graph: Graph
    reference: NDArray[np.float64]  # (T+2, 3)
    frame: str
    offsets: NDArray[np.float64]  # (n, 2) at scale 1
    scales: tuple[tr.Sinusoid | tr.AxisScales, ...]  # one per robot
    law: LawSettings
    uncertainty: Uncertainty
    source: str = "<memory>"
    text: str = field(default="", repr=False)
    #: desired headings: 'chord', 'arc' (``trajectory.HEADINGS``) or 'auto' (chord for the
    #: Euler model, arc for any plant that drives arcs: ``for_plant``)
    headings: str = "auto"
    #: the reference and the formation stretched in time by this factor (samples x it,
    #: speeds / it, accelerations / it^2): a scenario too fast for a robot's limits fits
    time_scale: float = 1.0
    #: [s] the desired motion eases in from rest over the trial's first ``ramp`` seconds
    #: (``desired.ramp``): a reference that starts at speed (a step no time scale removes)
    #: fits a base's acceleration limit; 0: none
    ramp: float = 0.0
    #: with a ramp: the formation's seconds (of the unstretched trial) at t = 0..T+1
    warped: NDArray[np.float64] | None = field(default=None, repr=False)

    @property
    def n(self) -> int:
        return self.graph.n

    @property
    def heading_rule(self) -> str:
        """The headings ``desired`` uses: 'auto' reads as 'chord'."""
        return "chord" if self.headings == "auto" else self.headings

    def for_plant(self, model: str) -> Scenario:
        """This scenario for a plant model: 'auto' headings become 'chord' for 'euler'
        (the model the desired inputs are exact for) and 'arc' for anything else (the exact
        arc model, a physics engine, a real base: a robot that turns while it drives)."""
        if self.headings != "auto":
            return self
        return replace(self, headings="chord" if model == "euler" else "arc")

    @cached_property
    def desired(self) -> tr.Desired:
        """Desired outputs and inputs of every robot (built on first use: the costly part);
        ScenarioError if they are not finite (offsets, scales or reference too extreme)."""
        with np.errstate(all="ignore"):
            # the formation's scales are functions of seconds of the unstretched trial
            pos = tr.formation_positions(self.reference, self.offsets, list(self.scales),
                                         self.dt / self.time_scale, self.frame,
                                         times=self.warped)
            d = tr.desired_trajectories(pos, self.dt, self.reference, self.heading_rule)
        for what, a in (("outputs", d.eta), ("inputs", d.u)):
            if not np.isfinite(a).all():
                robot = int(np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).all(axis=1))[0])
                raise ScenarioError(f"{self.source}: formation: robot {robot + 1}'s desired "
                                    f"{what} are not finite (offsets, scales or reference "
                                    f"too extreme for float64)")
        return d

    def with_options(self, *, law: int | None = None, memory: str | None = None,
                     noise: bool = True, delay: bool = True, seed: int | None = None,
                     trials: int | None = None, headings: str | None = None,
                     time_scale: float | None = None) -> Scenario:
        """A copy with command-line overrides applied. A new ``time_scale`` reads the
        scenario's text again (its reference and sample count change); ScenarioError if it
        cannot be applied."""
        if time_scale is not None and float(time_scale) != self.time_scale:
            src = Path(self.source)
            base = src.parent if src.suffix in (".yaml", ".yml") else None
            again = scenario_from_text(self.text, self.source, base, time_scale=time_scale)
            # the text knows nothing of the overrides this copy already carries (a law,
            # a seed, a number of trials, noise or delays taken out): keep them
            was, now = self.uncertainty, again.uncertainty
            return replace(again, headings=self.headings).with_options(
                law=self.law.kind if law is None else law,
                memory=self.law.memory if memory is None else memory,
                noise=noise and (was.noisy or not now.noisy),
                delay=delay and (was.delay != DelayModel() or now.delay == DelayModel()),
                seed=self.seed if seed is None else seed,
                trials=self.trials if trials is None else trials, headings=headings)
        if headings is not None and headings not in ("auto",) + tr.HEADINGS:
            raise ScenarioError(f"{self.source}: desired.headings: must be one of auto, "
                                f"{', '.join(tr.HEADINGS)}; got {show(headings)}")
        unc = self.uncertainty
        if not noise:
            unc = unc.without_noise()
        if not delay:
            unc = unc.without_delay()
        ls = self.law
        if law is not None or memory is not None:
            ls = replace(ls, kind=ls.kind if law is None else int(law),
                         memory=ls.memory if memory is None else memory)
        return replace(self, uncertainty=unc, law=ls,
                       seed=self.seed if seed is None else int(seed),
                       trials=self.trials if trials is None else int(trials),
                       headings=self.headings if headings is None else headings)


def _harmonics(f: Fields, key: str, count: int, angle_index: tuple[int, ...]
               ) -> tuple[Harmonic, ...]:
    items = f.get(key, [{}] * count)
    if not isinstance(items, list) or len(items) != count:
        raise f.fail(key, f"expected a list of {count} harmonics {{amplitude, frequency, phase}}")
    out = []
    for i, item in enumerate(items):
        h = Fields(item, f"{f.path}.{key}[{i}]", f.src)
        out.append(Harmonic(h.number("amplitude", 0.0, angle=i in angle_index),
                            h.number("frequency", 0.0), h.number("phase", 0.0, angle=True)))
        h.finish()
    return tuple(out)


def _constant(value: float) -> Any:
    return lambda t: np.full(np.shape(t), value)


#: references built, by their mapping, samples and dt: the configurations of a study share
#: one (a unicycle reference takes about 0.4 s to integrate)
_REFERENCES: dict[str, NDArray] = {}


def _reference(f: Fields, n_samples: int, dt: float, base_dir: Path | None,
               time_scale: float = 1.0) -> NDArray:
    """The reference on t = 0..T+1; with ``time_scale`` s, ``n_samples`` is the stretched
    count and sample t is where the unstretched reference is at t / s."""
    key = None
    if "file" not in f.data:  # a file's contents may change: read it every time
        try:
            key = json.dumps([f.data, n_samples, dt, time_scale], sort_keys=True)
        except (TypeError, ValueError):
            key = None
    if key is not None and key in _REFERENCES:
        return _REFERENCES[key].copy()  # the same mapping validated and built before
    ref = _build_reference(f, n_samples, dt, base_dir, time_scale)
    if key is not None:
        if len(_REFERENCES) >= 16:
            _REFERENCES.pop(next(iter(_REFERENCES)))
        _REFERENCES[key] = ref.copy()
    return ref


def _build_reference(f: Fields, n_samples: int, dt: float, base_dir: Path | None,
                     time_scale: float = 1.0) -> NDArray:
    kind = f.string("kind", choices=("lemniscate", "unicycle", "samples", "waypoints"))
    m = n_samples + 2  # t = 0..T+1
    if time_scale != 1.0 and kind == "samples":
        raise f.fail("kind", "a sampled reference cannot be stretched in time (time_scale); "
                             "give its points at the slower pace")
    # stretched: sample t sits at t / s of the unstretched grid, whose step is dt / s
    dt = dt / time_scale
    if kind == "lemniscate":
        ref = tr.paper_lemniscate(m, dt, f.number("x_amplitude", 7.5),
                                  f.number("y_amplitude", 10.0), f.number("period", 45.0,
                                                                          positive=True))
    elif kind == "unicycle":
        speed = f.get("speed", required=True)
        if speed == "paper-ivb":
            v = tr.paper_ivb_speed
        elif isinstance(speed, (int, float)) and not isinstance(speed, bool):
            v = _constant(f.as_number(speed, "speed"))
        else:
            raise f.fail("speed", f"expected 'paper-ivb' or a number [m/s], got {show(speed)}")
        radius = f.number("turn_radius", 0.0)
        if time_scale != 1.0:
            v0 = v
            v = lambda t: v0(np.asarray(t) / time_scale)  # noqa: E731
        w = (lambda t: v(t) / radius) if radius != 0 else _constant(0.0)
        start = f.numbers("start", 3, [0.0, 0.0, 0.0], angle_index=(2,))
        ref = tr.unicycle_reference(v, w, m, dt, (start[0], start[1], start[2]))
    elif kind == "samples":
        pts = f.get("points", None)
        file = f.get("file", None)
        if (pts is None) == (file is None):
            raise f.fail(None, "give exactly one of 'points' (a list of [x, y]) or 'file' (CSV)")
        if file is not None:
            if not isinstance(file, str):
                raise f.fail("file", f"expected a file name, got {show(file)}")
            path = Path(file) if base_dir is None else base_dir / file
            pts = _read_points(f, path, m)
        try:
            arr = np.asarray(pts, dtype=float)
        except (TypeError, ValueError):
            raise f.fail("points", "expected a list of [x, y] pairs") from None
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise f.fail("points", f"expected a list of [x, y] pairs, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise f.fail("points" if file is None else "file", "every point must be finite")
        if len(arr) < m - 1:
            raise f.fail("points", f"needs at least samples + 1 = {m - 1} points, got {len(arr)}")
        ref = tr.sampled_reference(arr, m)
    else:
        times = f.get("times", required=True)
        pts = f.get("points", required=True)
        try:
            ta = np.asarray(times, dtype=float)
            pa = np.asarray(pts, dtype=float)
        except (TypeError, ValueError):
            raise f.fail("points", "times must be numbers and points [x, y] pairs") from None
        if ta.ndim != 1 or pa.shape != (len(ta), 2) or len(ta) < 2:
            raise f.fail("points", "needs as many [x, y] points as times, at least 2")
        for key, arr in (("times", ta), ("points", pa)):
            if not np.isfinite(arr).all():
                raise f.fail(key, "every value must be finite")
        if np.any(np.diff(ta) <= 0):
            raise f.fail("times", "must be strictly increasing")
        ref = tr.waypoint_reference(ta, pa, m, dt)
    f.finish()
    if not np.isfinite(ref).all():
        bad = int(np.flatnonzero(~np.isfinite(ref).all(axis=1))[0])
        raise f.fail(None, f"the {kind} reference is not finite from sample {bad} on (a value "
                           f"too large or too small for float64?)")
    return ref


def _read_points(f: Fields, path: Path, rows: int) -> NDArray[np.float64]:
    """The first ``rows`` points (x, y) of a CSV file, its size bounded before it is read."""
    limit = MAX_FILE_BYTES + 256 * rows
    try:
        if not path.is_file():
            raise f.fail("file", f"cannot read {path}: " + (
                "not a regular file" if path.exists() else "no such file"))
        size = path.stat().st_size
        if size > limit:
            raise f.fail("file", f"cannot read {path}: {format_bytes(size)} is more than "
                                 f"{rows} points need (at most {format_bytes(limit)})")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # blank lines do not count: fine
            pts = np.loadtxt(path, delimiter=",", ndmin=2, comments="#", max_rows=rows,
                             encoding="utf-8")
        if pts.shape[1] < 2:
            raise f.fail("file", f"cannot read {path}: expected rows x,y, got one column")
        return np.asarray(pts[:, :2], dtype=float)
    except (OSError, ValueError, IndexError, UnicodeDecodeError) as exc:
        if isinstance(exc, ScenarioError):
            raise
        raise f.fail("file", f"cannot read {path}: {one_line(str(exc))}") from None


def _graph(f: Fields, n: int) -> Graph:
    leader_raw = f.get("leader", required=True)
    if not isinstance(leader_raw, dict) or not leader_raw:
        raise f.fail("leader", "expected a mapping {robot: weight} with at least one robot")
    leader = {}
    for k, v in leader_raw.items():
        r = f.robot(k, f"leader.{k}", n)
        leader[r] = f.as_number(v, f"leader.{k}", positive=True)
    edges_raw = f.get("edges", [])
    if not isinstance(edges_raw, list):
        raise f.fail("edges", "expected a list of {from, to, weight}")
    edges = []
    seen = set()
    for idx, e in enumerate(edges_raw):
        ef = Fields(e, f"{f.path}.edges[{idx}]", f.src)
        src = ef.robot(ef.get("from", required=True), "from", n)
        dst = ef.robot(ef.get("to", required=True), "to", n)
        w = ef.number("weight", 1.0, positive=True)
        ef.finish()
        if src == dst:
            raise ef.fail("to", f"robot {dst} cannot listen to itself")
        if (dst, src) in seen:
            raise ef.fail(None, f"duplicate edge {src} -> {dst}")
        seen.add((dst, src))
        edges.append((dst, src, w))
    f.finish()
    return Graph.from_edges(n, edges, leader)


def _per_robot(f: Fields, key: str, n: int, default: float) -> tuple[float, ...]:
    v = f.get(key, default)
    if isinstance(v, list):
        if len(v) != n:
            raise f.fail(key, f"expected one gain per robot ({n}), got {len(v)}")
        return tuple(f.as_number(x, f"{key}[{i}]", nonneg=True) for i, x in enumerate(v))
    return (f.as_number(v, key, nonneg=True),) * n


def scenario_from_text(text: str, source: str = "<memory>", base_dir: Path | None = None,
                       time_scale: float | None = None) -> Scenario:
    """Parse and validate a scenario given as YAML text.

    Every failure is a ScenarioError reading ``source: field: reason``, raised before the
    memory is spent: a document whose aliases or nesting would cost too much is refused
    unbuilt (``parse_yaml``), and one whose arrays would not fit in the memory available
    is refused before they are allocated (``load_bytes``).
    """
    data = parse_yaml(text, source)
    return scenario_from_data(data, text, source, base_dir, time_scale)


def scenario_from_data(data: Any, text: str, source: str = "<memory>",
                       base_dir: Path | None = None, time_scale: float | None = None
                       ) -> Scenario:
    """Validate a scenario given as the data ``parse_yaml`` makes of ``text`` (mappings,
    lists, strings, numbers; not modified); ``text`` is kept as the scenario's text. What
    ``scenario_from_text`` does after parsing: a study that edits the parsed data of one
    scenario need not write it out and parse it again."""
    with _section(source, "top level"):
        return _scenario(data, text, source, base_dir, time_scale)


@contextmanager
def _section(source: str, name: str) -> Iterator[None]:
    """Any error the field checks did not foresee still names the file and the part."""
    try:
        yield
    except ScenarioError:
        raise
    except (ValueError, TypeError, ArithmeticError, LookupError) as exc:
        raise ScenarioError(f"{source}: {name}: {one_line(str(exc)) or type(exc).__name__}"
                            ) from None


def load_bytes(samples: int, robots: int) -> int:
    """Peak memory [bytes] of loading a scenario of ``robots`` x ``samples``: the reference
    and its headings (measured: 1.29 GB at 10^7 samples, 6 robots) and the graph's dense
    robots x robots matrices."""
    return 160 * (samples + 2) + 64 * robots * robots + 512 * robots


def _name(f: Fields) -> str:
    name = f.string("name")
    if not name.strip() or len(name) > _MAX_NAME:
        raise f.fail("name", f"must be 1 to {_MAX_NAME} characters, got {len(name)}")
    if name in (".", "..") or any(c in name for c in "/\\") or not name.isprintable():
        raise f.fail("name", f"names the output folder: no '/', '\\' or control characters, "
                             f"got {show(name)}")
    return name


def _scenario(data: Any, text: str, source: str, base_dir: Path | None,
              time_scale: float | None = None) -> Scenario:
    top = Fields(data, "", source)
    name = _name(top)
    description = top.string("description", "")
    dt = top.number("dt")
    if dt <= 0:
        raise top.fail("dt", f"the sample time must be > 0 s, got {dt}")
    n_samples = top.integer("samples", minimum=2)
    trials = top.integer("trials", 100, minimum=1)
    seed = top.integer("seed", 0, minimum=0)
    n = top.integer("robots", minimum=1)
    with _section(source, "desired"):
        headings, scale, ramp = _desired_options(top, time_scale)
    n_samples = max(2, int(round(n_samples * scale)))
    why = memory_shortfall(load_bytes(n_samples, n))
    if why is not None:
        big = "samples" if 160 * n_samples >= 64 * n * n else "robots"
        raise top.fail(big, f"{n} robots x {n_samples} samples: loading them {why}")

    warped = None
    with _section(source, "reference"), np.errstate(all="ignore"):
        if ramp > 0:
            ref, warped = _ramped_reference(top, n_samples, dt, base_dir, scale, ramp)
        else:
            ref = _reference(top.sub("reference"), n_samples, dt, base_dir, scale)

    with _section(source, "formation"):
        frame, offsets, robot_scales = _formation(top.sub("formation"), n, source)
    with _section(source, "graph"):
        graph = _graph(top.sub("graph"), n)
    with _section(source, "law"):
        law = _law(top, n)
    with _section(source, "uncertainty"):
        unc_parts = _uncertainty(top)
    with _section(source, "delay"):
        dm, leader_link, loss = _delay(top, n_samples)
    top.finish()

    shift, dist_fixed, dist_unif, noise_fixed, noise_unif = unc_parts
    unc = Uncertainty((shift[0], shift[1], shift[2]), (dist_fixed[0], dist_fixed[1]),
                      (dist_unif[0], dist_unif[1]),
                      (noise_fixed[0], noise_fixed[1], noise_fixed[2]),
                      (noise_unif[0], noise_unif[1], noise_unif[2]), dm, leader_link, loss)
    return Scenario(name=name, description=description, dt=dt, samples=n_samples, trials=trials,
                    seed=seed, graph=graph, reference=ref, frame=frame, offsets=offsets,
                    scales=tuple(robot_scales), law=law, uncertainty=unc, source=source,
                    text=text, headings=headings, time_scale=scale, ramp=ramp, warped=warped)


#: how much finer than the sample grid a ramped reference is built, then read at the
#: warped times
RAMP_FINE = 10


def ramp_seconds(t: NDArray[np.float64], ramp: float) -> NDArray[np.float64]:
    """The warped time of trial time ``t`` [s] with a ramp of ``ramp`` seconds: its rate
    eases from 0 to 1 as 3 x^2 - 2 x^3 (x = t / ramp; the speed and the acceleration start
    at 0, the acceleration ends at 0), then runs on half a ramp behind."""
    x = np.clip(t / ramp, 0.0, 1.0)
    return np.where(t < ramp, ramp * (x ** 3 - 0.5 * x ** 4), t - 0.5 * ramp)


def _ramped_reference(top: Fields, n_samples: int, dt: float, base_dir: Path | None,
                      scale: float, ramp: float) -> tuple[NDArray, NDArray]:
    """The reference on t = 0..T+1 read at the warped times (``ramp_seconds``), from the
    same reference built RAMP_FINE times finer; and the formation's warped seconds."""
    f = top.sub("reference")
    q = RAMP_FINE
    fine = _reference(f, (n_samples + 1) * q, dt, base_dir, scale * q)  # step dt / q
    t: NDArray[np.float64] = np.arange(n_samples + 2, dtype=np.float64) * dt
    tau = ramp_seconds(t, ramp)
    at = tau / (dt / q)
    grid = np.arange(len(fine))
    heading = np.unwrap(fine[:, 2])
    ref = np.stack([np.interp(at, grid, fine[:, 0]), np.interp(at, grid, fine[:, 1]),
                    np.interp(at, grid, heading)], axis=1)
    return ref, tau / scale


#: the most a trial may be stretched in time (a typo like 100 would make it 100 x longer)
MAX_TIME_SCALE = 20.0


def _desired_options(top: Fields, time_scale: float | None) -> tuple[str, float, float]:
    """``desired: {headings, time_scale, ramp}``; ``time_scale`` given (the command line's
    ``--time-scale``) replaces the file's."""
    df = top.sub("desired", required=False)
    headings = df.string("headings", "auto", choices=("auto",) + tr.HEADINGS)
    scale = df.number("time_scale", 1.0, positive=True)
    ramp = df.number("ramp", 0.0, nonneg=True)
    ref_data = top.data.get("reference") if isinstance(top.data, dict) else None
    if ramp > 0 and isinstance(ref_data, dict) and ref_data.get("kind") == "samples":
        raise df.fail("ramp", "a sampled reference cannot be eased in (its points are its "
                              "pace); give them from rest")
    df.finish()
    if time_scale is not None:
        scale = float(time_scale)
        if not math.isfinite(scale) or scale <= 0:
            raise df.fail("time_scale", f"must be > 0, got {time_scale} (--time-scale)")
    if not 1.0 <= scale <= MAX_TIME_SCALE:
        raise df.fail("time_scale", f"must be in [1, {MAX_TIME_SCALE:g}] (a factor that "
                                    f"slows the trial down), got {scale:g}")
    return headings, scale, ramp


def _formation(ff: Fields, n: int, source: str
               ) -> tuple[str, NDArray[np.float64], list[tr.Sinusoid | tr.AxisScales]]:
    frame = ff.string("frame", choices=("world", "leader"))
    scales_raw = ff.get("scales", {})
    if not isinstance(scales_raw, dict):
        raise ff.fail("scales", "expected a mapping name -> {mean, amplitude, period, phase}")
    scales: dict[str, tr.Sinusoid] = {}
    for key, val in scales_raw.items():
        sf = Fields(val, f"formation.scales.{key}", source)
        scales[str(key)] = tr.Sinusoid(sf.number("mean", 1.0), sf.number("amplitude", 0.0),
                                       sf.number("period", 0.0, nonneg=True),
                                       sf.number("phase", 0.0, angle=True))
        sf.finish()
    off_raw = ff.get("offsets", required=True)
    if not isinstance(off_raw, dict):
        raise ff.fail("offsets", "expected a mapping robot -> {x, y, scale}")
    offsets = np.full((n, 2), np.nan)
    robot_scales: list[tr.Sinusoid | tr.AxisScales] = [tr.Sinusoid()] * n
    for key, val in off_raw.items():
        r = ff.robot(key, f"offsets.{key}", n)
        of = Fields(val, f"formation.offsets.{key}", source)
        offsets[r - 1] = (of.number("x"), of.number("y"))
        sname = of.get("scale", None)
        if sname is not None:
            # one scale, or [x, y]: one per axis of the offset
            names = sname if isinstance(sname, list) else [sname]
            if len(names) not in (1, 2):
                raise of.fail("scale", f"a scale's name or a list of two [x, y], got "
                                       f"{len(names)} names")
            for k, name in enumerate(names):
                if not isinstance(name, str) or name not in scales:
                    where = "scale" if len(names) == 1 else f"scale[{k}]"
                    raise of.fail(where, f"no scale named {show(name)} in formation.scales "
                                         f"(have: {one_line(', '.join(scales), 80) or 'none'})")
            robot_scales[r - 1] = (scales[names[0]] if len(names) == 1
                                   else tr.AxisScales(scales[names[0]], scales[names[1]]))
        of.finish()
    missing = [str(i + 1) for i in range(n) if np.isnan(offsets[i, 0])]
    if missing:
        more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
        raise ff.fail("offsets", f"no offset for robot(s) {', '.join(missing[:10])}{more}")
    ff.finish()
    return frame, offsets, robot_scales


def _law(top: Fields, n: int) -> LawSettings:
    lf = top.sub("law", required=False)
    law = LawSettings(
        kind=int(lf.integer("kind", 9)),
        memory=lf.string("memory", "feedforward", choices=MEMORY_MODES),
        gain=_per_robot(lf, "gain", n, 0.08),
        gain_prime=_per_robot(lf, "gain_prime", n, 0.08),
        gain_heading=lf.string("gain_heading", "measured", choices=HEADING_SOURCES),
    )
    if law.kind not in LAWS:
        raise lf.fail("kind", f"must be one of {', '.join(map(str, LAWS))}; got {law.kind}")
    lf.finish()
    return law


def _uncertainty(top: Fields) -> tuple[Any, ...]:
    uf = top.sub("uncertainty", required=False)
    shift = uf.numbers("initial_shift", 3, [0, 0, 0], nonneg=True, angle_index=(2,))
    df = uf.sub("disturbance", required=False)
    dist_fixed = _harmonics(df, "fixed", 2, (1,))
    dist_unif = df.numbers("uniform", 2, [0, 0], nonneg=True, angle_index=(1,))
    df.finish()
    nf = uf.sub("noise", required=False)
    noise_fixed = _harmonics(nf, "fixed", 3, (2,))
    noise_unif = nf.numbers("uniform", 3, [0, 0, 0], nonneg=True, angle_index=(2,))
    nf.finish()
    uf.finish()
    return shift, dist_fixed, dist_unif, noise_fixed, noise_unif


def _delay(top: Fields, n_samples: int) -> tuple[DelayModel, bool, float]:
    dlf = top.sub("delay", required=False)
    model = dlf.string("model", "none", choices=("none", "fixed", "uniform", "table", "paper"))
    try:
        if model == "paper":
            dm = DelayModel.paper()
        elif model == "fixed":
            dm = DelayModel("fixed", samples=dlf.integer("samples", minimum=0))
        elif model == "uniform":
            dm = DelayModel("uniform", low=dlf.integer("low", minimum=0),
                            high=dlf.integer("high", minimum=0))
        elif model == "table":
            vals = dlf.get("values", required=True)
            probs = dlf.get("probabilities", required=True)
            if not isinstance(vals, list) or not all(
                    isinstance(v, int) and not isinstance(v, bool) for v in vals):
                raise dlf.fail("values", "expected a list of delays in samples (integers)")
            twice = sorted(v for v, c in Counter(vals).items() if c > 1)
            if twice:
                # the pmf maps each delay to one probability: a repeat would lose its mass
                raise dlf.fail("values", f"delay {twice[0]} is listed twice")
            if not isinstance(probs, list) or len(probs) != len(vals):
                raise dlf.fail("probabilities", "expected one probability per value")
            dm = DelayModel("table", values=tuple(vals),
                            probabilities=tuple(dlf.as_number(p, f"probabilities[{i}]",
                                                              nonneg=True)
                                                for i, p in enumerate(probs)))
        else:
            dm = DelayModel()
    except ValueError as exc:
        if isinstance(exc, ScenarioError):
            raise
        raise dlf.fail(None, one_line(str(exc))) from None
    loss = dlf.number("loss", 0.0, nonneg=True)
    if loss >= 1.0:
        raise dlf.fail("loss", f"a probability below 1 is required, got {loss}")
    leader_link = dlf.get("leader_link", True)
    if not isinstance(leader_link, bool):
        raise dlf.fail("leader_link", f"expected true or false, got {show(leader_link)}")
    if dm.max_delay > n_samples:
        raise dlf.fail(None, f"delays of up to {dm.max_delay} samples exceed the trial "
                             f"({n_samples} samples)")
    dlf.finish()
    return dm, leader_link, loss


def load_scenario(name_or_path: str | Path) -> Scenario:
    """Load a built-in scenario by name, or a YAML file by path (at most MAX_FILE_BYTES)."""
    name = str(name_or_path)
    if not name.strip():
        raise ScenarioError("SCENARIO: empty; give a built-in name "
                            f"({', '.join(builtin_scenarios())}) or a YAML file")
    p = Path(name_or_path)
    try:
        is_file_arg = p.suffix in (".yaml", ".yml") or p.exists()
    except (OSError, ValueError) as exc:  # e.g. a name too long for the file system
        raise ScenarioError(f"{printable(name, 80)}: cannot read: "
                            f"{getattr(exc, 'strerror', None) or exc}") from None
    if is_file_arg:
        text = read_text_file(p)
        return scenario_from_text(text, str(p), p.parent)
    if name in builtin_scenarios():
        text = resources.files(SCENARIO_PACKAGE).joinpath(name + ".yaml").read_text()
        return scenario_from_text(text, f"{name} (built-in)")
    raise ScenarioError(f"{printable(name, 80)}: no such scenario file, and not a built-in "
                        f"scenario (built-in: {', '.join(builtin_scenarios())})")
