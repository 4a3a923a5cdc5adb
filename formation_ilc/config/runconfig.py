"""The run configuration every node of the stack shares.

It travels on the ``config`` topic (latched) as JSON: the scenario's YAML text and the
command-line overrides, so that no node needs the scenario file, and a recording carries it.
The leader, which publishes it, gets it as ROS parameters (``RunConfig.to_params`` and
``RunConfig.from_params``, the one mapping between the two; ``param_text`` writes a value
for ``--ros-args -p NAME:=VALUE``).
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from formation_ilc.config.clocks import ClockSettings
from formation_ilc.config.safety import SafetySettings
from formation_ilc.config.scenario import Scenario, load_scenario, scenario_from_text
from formation_ilc.core.clock import Rejected, SampleClock, WallGrid
from formation_ilc.core.links import LINK_MODES
from formation_ilc.core.names import MONITOR_NODE, RECORDER_NODE

__all__ = ["RunConfig", "make_config", "MODES", "WALL_MODES", "PARAMS", "param_text",
           "scenario_reference", "clocks_param", "disagreement"]

MODES = ("lockstep", "realtime", "wallclock")
#: modes in which the plant does not wait for commands (missed samples are held)
WALL_MODES = ("realtime", "wallclock")

#: the ROS parameters of a run configuration and their defaults: seed -1, trials 0, law 0
#: and memory "" keep the scenario's; noise and delay false are ``--no-noise`` and
#: ``--no-delay``; headings "" and time_scale 0 keep the scenario's desired headings and
#: time scale (``RunConfig.to_params``, ``RunConfig.from_params``)
PARAMS: dict[str, Any] = {
    "scenario": "", "seed": -1, "trials": 0, "law": 0, "memory": "", "noise": True,
    "delay": True, "mode": "lockstep", "links": "emulated", "gap": 20, "monitored": False,
    "recorded": False, "timeout": 30.0, "run_id": "", "headings": "", "time_scale": 0.0,
    "safety": ""}


def param_text(value: Any) -> str:
    """``value`` as written after ``-p NAME:=`` on a command line. ROS reads it as YAML:
    booleans lower case, a list of strings ``[a,b]``, and a string YAML would read as
    something else (empty, ``true``, ``123``) single-quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(str(v) for v in value) + "]"
    text = str(value)
    if isinstance(value, str) and _yaml_reads(text) != value:
        return "'" + text.replace("'", "''") + "'"
    return text


def _yaml_reads(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return None


def scenario_reference(scenario: str) -> str:
    """What another process loads ``scenario`` by: a file's absolute path (the process may
    run elsewhere), or the built-in name."""
    return str(Path(scenario).resolve()) if Path(scenario).exists() else scenario


@dataclass(frozen=True)
class RunConfig:
    """Everything a node needs to know about a run.

    mode : 'lockstep' (the plant waits for every robot), 'realtime' (a simulator ticks on
        the wall clock and owns /clock) or 'wallclock' (no /clock at all: the leader's
        ``start`` event carries an agreed wall time ``start_wall_ns`` and every node samples
        on its own wall clock at start_wall_ns + s * dT; real robots behind bridges).
        Robots treat 'wallclock' as 'realtime' (missed samples held, bounded link waits).
    links : 'emulated' (the link emulator applies the scenario's delays in simulated time) or
        'direct' (robots subscribe to their neighbours; delays are the network's).
    gap : samples between the end of one trial's labels and the next trial's (stamps).
    monitored : a monitor (the launcher) reads trajectories and diagnostics.
    recorded : a recorder writes the run to a file. With ``monitored``, it names the
        readers a node that publishes trajectories waits for (``result_readers``).
    timeout : [s] lockstep: how long the plant waits for a robot's command.
    run_id : identity of the run (set by the launcher): a node that has taken this
        configuration refuses another run's on the same domain and namespace.
    safety : the safety filter every robot's command goes through
        (``config.safety.SafetySettings``), or None: the learned command is sent as it is.
    clocks : the clock exchanges of realtime and wall-clock runs, and emulated clocks
        (``config.clocks.ClockSettings``).
    """

    scenario: Scenario
    mode: str = "lockstep"
    gap: int = 20
    monitored: bool = False
    timeout: float = 30.0
    links: str = "emulated"
    run_id: str = ""
    recorded: bool = False
    safety: SafetySettings | None = None
    clocks: ClockSettings = ClockSettings()

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        if self.links not in LINK_MODES:
            raise ValueError(f"links must be one of {', '.join(LINK_MODES)}, got {self.links!r}")
        if self.mode == "wallclock" and self.links != "direct":
            raise ValueError("mode wallclock needs links direct: the link emulator ticks on "
                             "/clock, which no node publishes in wall-clock trials")
        if self.clocks.emulated and not self.wall:
            raise ValueError("emulated clocks need mode realtime or wallclock: in lockstep "
                             "every node runs on the simulated clock, and no robot's own "
                             "clock is read")

    @property
    def clock_exchanges(self) -> bool:
        """The robots and bridges exchange clock stamps with the nodes they hear:
        realtime and wall-clock runs (in simulated time no node reads a clock). Whether
        they estimate the clocks from them is ``clocks.sync``."""
        return self.wall

    @property
    def wall(self) -> bool:
        """The plant does not wait for commands (realtime or wallclock)."""
        return self.mode in WALL_MODES

    @property
    def leader_in_step(self) -> bool:
        """Whether a robot that sees the leader takes the leader link from its own sample
        rather than from the per-sample reference messages: in lockstep with direct links.
        There the robot waits for St = Rt on every link, so the reference of its sample t
        is labelled t (delay 0, eq. 11), and the law reads the reference itself from the
        scenario (eq. 9 uses only the label's sample of the leader link): the message would
        carry nothing the robot does not have. The leader still broadcasts every sample's
        reference (the recorder and the live view read it). In realtime and wallclock
        trials the leader link's delay is the network's, and with emulated links the
        emulator delays it: there the robots take what arrives."""
        return self.mode == "lockstep" and self.links == "direct"

    @property
    def result_readers(self) -> tuple[str, ...]:
        """The node names that must read every trajectory (measured and true): the
        launcher's monitor and the recorder, as this run has them. A count of matched
        readers cannot stand for them: the recorder, a live view or a user's tool reads
        the same topics, and a trajectory sent before the monitor has matched its writer
        is gone for it once two more are sent (the writers keep two)."""
        return ((MONITOR_NODE,) if self.monitored else ()) + \
            ((RECORDER_NODE,) if self.recorded else ())

    @functools.cached_property
    def clock(self) -> SampleClock | WallGrid:
        """The run's sample grid: simulated-time labels, or in ``wallclock`` mode real
        time (``WallGrid``, which learns each slot's agreed start: one per configuration,
        so every part of a node sees the starts it took)."""
        grid = SampleClock.for_run(self.scenario.dt, self.scenario.samples, self.gap)
        if self.mode == "wallclock":
            return WallGrid(grid.dt_ns, grid.samples, grid.period)
        return grid

    def to_json(self) -> dict[str, Any]:
        sc = self.scenario
        return {"scenario_text": sc.text, "source": sc.source, "seed": sc.seed,
                **_switches(sc), "trials": sc.trials,
                "law": sc.law.kind, "memory": sc.law.memory, "mode": self.mode,
                "links": self.links, "gap": self.gap, "monitored": self.monitored,
                "recorded": self.recorded, "timeout": self.timeout, "run_id": self.run_id,
                "headings": sc.headings, "time_scale": sc.time_scale,
                "safety": None if self.safety is None else self.safety.to_json(),
                "clocks": self.clocks.to_json()}

    @property
    def scenario_param(self) -> str:
        """The ``scenario`` parameter of this configuration: a built-in's name, or the file
        it was loaded from."""
        sc = self.scenario
        return sc.name if sc.source.endswith("(built-in)") else sc.source

    def agreement(self) -> dict[str, Any]:
        """What every node of one run must agree on (its ``ready`` carries it): the
        scenario (name and text), the draws, the law, the time grid, the links, the
        filter. Two nodes that differ here would not run one team."""
        import hashlib

        sc = self.scenario
        return {"scenario": sc.name,
                "scenario_text": hashlib.sha256(sc.text.encode()).hexdigest()[:12],
                "seed": sc.seed, **_switches(sc), "law": sc.law.kind,
                "memory": sc.law.memory, "mode": self.mode, "links": self.links,
                "gap": self.gap, "headings": sc.headings, "time_scale": float(sc.time_scale),
                "safety": None if self.safety is None else self.safety.to_json()}

    def to_params(self, scenario: str) -> dict[str, Any]:
        """The ROS parameters (PARAMS) of this configuration; ``scenario`` is the name or
        file its scenario was loaded from (``scenario_reference``). Every value is
        explicit, so ``from_params`` gives this configuration back (but for ``clocks``:
        the leader's own parameter of that name, ``clocks_param``)."""
        sc = self.scenario
        return {"scenario": scenario, "seed": sc.seed, "trials": sc.trials,
                "law": sc.law.kind, "memory": sc.law.memory, **_switches(sc),
                "mode": self.mode, "links": self.links, "gap": self.gap,
                "monitored": self.monitored, "recorded": self.recorded,
                "timeout": float(self.timeout),
                "run_id": self.run_id, "headings": sc.headings,
                "time_scale": float(sc.time_scale),
                "safety": "" if self.safety is None else json.dumps(self.safety.to_json())}

    @classmethod
    def from_params(cls, p: Mapping[str, Any]) -> RunConfig:
        """The configuration of ROS parameters (PARAMS; missing ones take their default):
        loads the scenario; ValueError (a ScenarioError for the scenario) naming what is
        wrong."""
        g = {**PARAMS, **p}
        if not g["scenario"]:
            raise ValueError("parameter scenario: a scenario name or file is required")
        safety = None
        if g["safety"]:
            try:
                safety = SafetySettings.from_json(json.loads(str(g["safety"])))
            except (ValueError, Rejected) as exc:
                raise ValueError(f"parameter safety: JSON of the filter's settings "
                                 f"(formation_ilc.config.safety), got {str(g['safety'])[:80]!r}: "
                                 f"{exc}") from None
        return make_config(
            str(g["scenario"]), seed=None if int(g["seed"]) < 0 else int(g["seed"]),
            noise=bool(g["noise"]), delay=bool(g["delay"]), trials=int(g["trials"]) or None,
            law=int(g["law"]) or None, memory=str(g["memory"]) or None, mode=str(g["mode"]),
            gap=int(g["gap"]), monitored=bool(g["monitored"]), recorded=bool(g["recorded"]),
            timeout=float(g["timeout"]), links=str(g["links"]), run_id=str(g["run_id"]),
            headings=str(g["headings"]) or None, time_scale=float(g["time_scale"]) or None,
            safety=safety)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunConfig:
        """The configuration of a JSON object; Rejected (malformed) naming what is wrong."""
        try:
            sc = scenario_from_text(str(d["scenario_text"]), str(d.get("source", "<config>")))
            sc = sc.with_options(law=int(d["law"]), memory=str(d["memory"]),
                                 noise=bool(d["noise"]), delay=bool(d["delay"]),
                                 seed=int(d["seed"]), trials=int(d["trials"]),
                                 headings=str(d.get("headings", sc.headings)),
                                 time_scale=float(d.get("time_scale", sc.time_scale)))
            safety = d.get("safety")
            clocks = d.get("clocks")
            return cls(sc, str(d.get("mode", "lockstep")), int(d.get("gap", 20)),
                       bool(d.get("monitored", False)), float(d.get("timeout", 30.0)),
                       str(d.get("links", "emulated")), str(d.get("run_id", "")),
                       bool(d.get("recorded", False)),
                       None if safety is None else SafetySettings.from_json(safety),
                       ClockSettings() if clocks is None else ClockSettings.from_json(clocks))
        except (KeyError, TypeError, ValueError) as exc:
            raise Rejected("malformed", f"bad run configuration: {exc}") from None


def clocks_param(text: str) -> ClockSettings:
    """The clock settings of the leader's ``clocks`` parameter (JSON of
    ``config.clocks.ClockSettings``; empty: the defaults); ValueError naming what is
    wrong. A parameter of the leader's beside PARAMS: a launch without clock options keeps
    its command line."""
    if not text:
        return ClockSettings()
    try:
        return ClockSettings.from_json(json.loads(text))
    except (ValueError, Rejected) as exc:
        raise ValueError(f"parameter clocks: JSON of the clock settings "
                         f"(formation_ilc.config.clocks), got {text[:80]!r}: {exc}") from None


def disagreement(mine: dict[str, Any], theirs: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """The fields of two ``RunConfig.agreement`` on which they differ: (field, mine,
    theirs), in the order of ``mine``; a field only one of them has is not compared."""
    return [(k, v, theirs[k]) for k, v in mine.items() if k in theirs and theirs[k] != v]


def _switches(sc: Scenario) -> dict[str, bool]:
    """noise and delay as ``Scenario.with_options`` takes them back: false strips them."""
    return {"noise": sc.uncertainty.noisy, "delay": sc.uncertainty.delay.kind != "none"}


def make_config(scenario: str, *, seed: int | None = None, noise: bool = True,
                delay: bool = True, trials: int | None = None, law: int | None = None,
                memory: str | None = None, mode: str = "lockstep", gap: int = 20,
                monitored: bool = False, timeout: float = 30.0,
                links: str = "emulated", run_id: str = "", headings: str | None = None,
                time_scale: float | None = None, recorded: bool = False,
                safety: SafetySettings | None = None,
                clocks: ClockSettings | None = None, text: str | None = None) -> RunConfig:
    """The run configuration of a scenario name or file with command-line overrides;
    ``text``: the file's text, when it is not written yet (a run file's own scenario)."""
    loaded = (load_scenario(scenario) if text is None else
              scenario_from_text(text, scenario, Path(scenario).parent))
    sc = loaded.with_options(law=law, memory=memory, noise=noise,
                                              delay=delay, seed=seed, trials=trials,
                                              headings=headings, time_scale=time_scale)
    return RunConfig(sc, mode, gap, monitored, timeout, links, run_id, recorded, safety,
                     clocks or ClockSettings())
