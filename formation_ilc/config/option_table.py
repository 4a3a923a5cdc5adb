"""Every option of a launched run, declared once.

One row per option: its run file key and section, its command-line flag, its kind, its
unit, its default, its help and the plants that use it. Everything else derives from this
table: the ``launch`` and ``run-file`` parser (``cli.launchargs``), ``LaunchOptions``'
defaults (``plan.options``), the run file's reader and writer (``cli.runfile``), the
refusal of an option a plant does not use, and the plant option classes
(``plan.specs.PhysicsOptions``, ``BridgeOptions``, ``RestartPolicy``) and the contact
parameters of the physics nodes. ``tests/config/test_option_table.py`` compares every
derived default with the table.

No argparse here: a row parses its value from text (``Option.parse``, ValueError with the
reason); the command line and a run file turn that into their own error lines.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from formation_ilc.config import values as V
from formation_ilc.config.bases import BASES
from formation_ilc.config.clocks import FALLBACKS
from formation_ilc.config.plants import PLANT_TABLE, PLANTS
from formation_ilc.config.roster import DRIVER_NS
from formation_ilc.config.runconfig import MODES
from formation_ilc.config.safety import BODIES, MOTION, TOLD_UP_TO, default_margin
from formation_ilc.core.links import LINK_MODES
from formation_ilc.core.names import NAMESPACE
from formation_ilc.core.safety import LEARNING
from formation_ilc.core.through import DAMPING, Q_SIGMA

__all__ = ["Option", "OPTIONS", "BY_FIELD", "SECTIONS", "GROUPS", "option", "default",
           "KINDS", "PATH_KINDS", "ON_CONTACT", "TILT_RANGE", "LIVE_PORT", "RobotEntry",
           "robot_entries"]

#: how an option's value is written and read:
#: int, float, str: one value (``choices`` and bounds checked by ``parse``);
#: bool: a flag (false unless given); switch: --X / --no-X, or unset (None);
#: path: a file or folder read; folder: a folder to write; file: a file to write;
#: names: one or more names; port: a TCP port, or the flag alone for ``const``;
#: stored: no flag: a stored run's own value (its id, ...); hosts: the run file's hosts:;
#: robots: the run file's robots: (RobotEntry, per robot)
KINDS = ("int", "float", "str", "bool", "switch", "path", "folder", "file", "names", "port",
         "stored", "hosts", "robots")
PATH_KINDS = ("path", "folder", "file")

#: what a physics plant does when robots touch: stop them and re-run the trial (at most
#: ``contact_retries`` times), stop them and end the run, or report and go on
ON_CONTACT = ("stop", "abort", "continue")
#: the live view's port when ``--live`` names none (Foxglove's usual)
LIVE_PORT = 8765
#: the tilt limits a plant takes [deg]
TILT_RANGE = (0.1, 180.0)

#: the sections of a run file, in the order it is written, and what each holds
SECTIONS: dict[str, str] = {
    "": "the run",
    "run": "the scenario's draws, the learning law and the reference",
    "plant": "the plant: what the robots are (formation-ilc launch --help: --plant)",
    "safety": "the safety filter and what a contact does (docs/safety.md)",
    "clocks": "the robots' clocks in realtime and wallclock runs",
    "processes": "how the processes run and are supervised",
    "network": "ROS networking, and robots on network namespaces (--hosts netns)",
    "recording": "what the run writes besides its output folder's tables",
    "live": "the Foxglove live view (docs/ros-tools.md)",
    "security": "DDS-Security (docs/security.md)",
}

#: the headings of ``launch --help``, in order: "" holds the options most runs need (one
#: screen); the others are for special runs
GROUPS: dict[str, str] = {
    "": "the options most runs need (the rest are for special runs, below)",
    "law": "for special runs: the run's reference and learning law",
    "plant": "for special runs: the plant's details (--plant)",
    "safety": "for special runs: the safety filter (docs/safety.md)",
    "processes": "for special runs: processes, ROS and the live view",
    "hosts": "for special runs: robots on separate hosts, one machine (root; "
             "docs/lossy-links.md)",
    "clocks": "for special runs: robots' clocks: realtime and wallclock runs "
              "(docs/distributed-stack.md, docs/real-robots.md)",
}

#: which plants use an option: (whether plant row ``p`` with options ``o`` does, the words
#: naming them); None: every plant
Uses = tuple[Callable[[Any, Any], bool], str]
_BRIDGES: Uses = (lambda p, o: p.per_robot, "--plant pioneer or base")
_PIONEER: Uses = (lambda p, o: p.driver == "pioneer", "--plant pioneer")
_BASE: Uses = (lambda p, o: p.driver == "base", "--plant base")
_PHYSICS: Uses = (lambda p, o: p.physics, "--plant physics")
_BODIES_SIM: Uses = (lambda p, o: p.physics or o.physics_bases,
                     "--plant physics or --physics-bases")
_TOUCH: Uses = (lambda p, o: p.physics or o.physics_bases,
                "--plant physics or --physics-bases: their bodies touch")
_TILT: Uses = (lambda p, o: p.physics or o.physics_bases,
               "--plant physics or --physics-bases: their bodies tilt")
_EXTERNAL: Uses = (lambda p, o: p.entry is None, "--plant external")


@dataclass(frozen=True, kw_only=True)
class Option:
    """One option of a launched run.

    field : its ``LaunchOptions`` field (and argparse destination).
    key : its run file key, ``section.name`` or a top-level name; None: none.
    flag : its command-line flag (``--safety-margin``; ``scenario`` for the positional);
        None: none (a stored run's own value).
    kind : KINDS.
    default : the value when it is not given; None: decided by the scenario, the plant
        or the machine (``default_text`` says which).
    help : what it does, for ``--help`` and the run file's comment (the default is added).
    unit : its unit ([m], [s], [deg/s], ...): a value may be written with another unit of
        its kind (``"1.7 rad/s"``, ``config.values.UNITS``).
    choices, lo, hi, open_lo : the values it takes.
    negated : the run file key is the field negated (``run.noise: false`` is ``--no-noise``).
    uses : the plants that use it (Uses); None: every plant.
    group : its heading in ``launch --help`` (GROUPS).
    metavar, const : as argparse's.
    stored_as : the type of a stored row's value.
    """

    field: str
    key: str | None
    flag: str | None
    kind: str
    default: Any = None
    help: str = ""
    default_text: str = ""
    unit: str = ""
    choices: tuple[Any, ...] | None = None
    lo: float | None = None
    hi: float | None = None
    open_lo: bool = False
    negated: bool = False
    uses: Uses | None = None
    group: str = "plant"
    metavar: str | None = None
    const: Any = None
    #: a stored row's type (str, int, or Path for a path)
    stored_as: type = str

    @property
    def section(self) -> str:
        """The run file section of its key ("" for a top-level key)."""
        return self.key.split(".", 1)[0] if self.key and "." in self.key else ""

    @property
    def is_path(self) -> bool:
        """Whether its value is a path (relative to a run file's folder in a file)."""
        return self.kind in PATH_KINDS or self.stored_as is Path

    def value(self, text: str) -> Any:
        """The value written as ``text``, its choices not checked (argparse checks them on
        the command line); ValueError with the reason."""
        if self.kind in ("int", "port"):
            lo = int(self.lo) if self.lo is not None else -(2 ** 63)
            value: Any = V.int_in(lo, None if self.hi is None else int(self.hi))(text)
        elif self.kind == "float":
            value = V.float_in(self.lo, self.hi, open_lo=self.open_lo, unit=self.unit)(text)
        else:
            value = text
        return value

    def parse(self, text: str) -> Any:
        """The value written as ``text``, one of its choices; ValueError with the reason."""
        value = self.value(text)
        if self.choices is not None and value not in self.choices:
            raise ValueError(f"invalid choice: {value!r} (choose from "
                             f"{', '.join(str(c) for c in self.choices)})")
        return value

    def help_text(self) -> str:
        """Its help with the plants that use it and its default, as ``--help`` and the run
        file's comments say it."""
        text = " ".join(self.help.split())
        if self.uses is not None:
            text = f"with {self.uses[1].split(':')[0]}: {text}"
        if self.unit in V.UNITS:  # an angle: also with its unit, in degrees or radians
            other = [u for u in V.UNITS[self.unit] if u != self.unit][0]
            text = f"{text} [{self.unit}; or with a unit, '1.2 {other}']"
        elif self.unit:
            text = f"{text} [{self.unit}]"
        if self.default_text:
            return f"{text} (default: {self.default_text})"
        if self.default in (None, ()) or self.kind in ("bool", "stored", "hosts"):
            return text
        shown = " ".join(map(str, self.default)) if isinstance(self.default, tuple) else (
            f"{self.default:g}" if isinstance(self.default, float) else str(self.default))
        return f"{text} (default {shown})"


def _o(field: str, key: str | None, flag: str | None, kind: str, **kw: Any) -> Option:
    return Option(field=field, key=key, flag=flag, kind=kind, **kw)


_PLANTS_HELP = "; ".join(f"{row.name}: {row.help}" for row in PLANT_TABLE)

OPTIONS: tuple[Option, ...] = (
    # ------------------------------------------------------------------ the run
    _o("scenario", "scenario", "scenario", "str", group="", metavar="SCENARIO",
       help="built-in scenario name (formation-ilc scenarios), a scenario YAML file, or a "
            "run file (formation-ilc run-file: every option of the run; an option given "
            "here overrides its key); not with --resume"),
    _o("scenario_text", None, None, "stored",
       help="a scenario written inline in a run file (its YAML text)"),
    _o("trials", "trials", "--trials", "int", default=20, lo=1, hi=V.MAX_TRIAL, group="",
       metavar="K", help="number of trials"),
    _o("law", "run.law", "--law", "int", choices=(9, 22, 23), group="law",
       default_text="the scenario's",
       help="9: predictive + delay-compensated current term (the paper's); 22: predictive "
            "only; 23: current term ignores the delay"),
    _o("memory", "run.memory", "--memory", "str", choices=("feedforward", "literal"),
       group="law", default_text="the scenario's, feedforward in the built-ins",
       help="what the learning memory holds (paper-notes 12): feedforward (the current "
            "term is feedback on top) or literal (the applied input, current term included)"),
    _o("seed", "run.seed", "--seed", "int", lo=0, hi=V.MAX_SEED, group="",
       default_text="the scenario's", help="random seed, >= 0"),
    _o("no_noise", "run.noise", "--no-noise", "bool", default=False, negated=True, group="",
       help="no initial shifts, disturbances or measurement noise"),
    _o("no_delay", "run.delay", "--no-delay", "bool", default=False, negated=True, group="",
       help="no communication delays"),
    _o("headings", "run.headings", "--headings", "str", choices=("auto", "chord", "arc"),
       group="law", default_text="the scenario's",
       help="desired headings (auto: chord for the Euler model and the kinematic "
            "simulator, arc for plants that drive arcs: docs/physics.md)"),
    _o("time_scale", "run.time_scale", "--time-scale", "float", lo=0.0, open_lo=True,
       group="law", metavar="S", default_text="the scenario's",
       help="stretch the reference in time by S >= 1 (S times slower: speeds / S, "
            "accelerations / S^2), so that a fast scenario fits the robots' limits"),
    _o("mode", "mode", "--mode", "str", choices=MODES, group="",
       default_text="the plant's: lockstep with the simulator, wallclock behind bridges",
       help="lockstep: the simulator waits for every robot (as fast as the processes "
            "allow, deterministic); realtime: the simulator ticks on the wall clock at dT; "
            "wallclock (required with --plant pioneer): no /clock, the trials run on the "
            "machines' synchronised wall clocks"),
    _o("links", "links", "--links", "str", choices=LINK_MODES, group="",
       default_text="emulated; direct behind bridges",
       help="emulated: a link emulator process puts the scenario's delays on the "
            "robot-to-robot links, in simulated time (a lockstep run equals `simulate`); "
            "direct: each robot subscribes to its neighbours, as on robots, and the delays "
            "are the network's (a lockstep run equals `simulate --no-delay`; required with "
            "--plant pioneer)"),
    # ------------------------------------------------------------------ the plant
    _o("plant", "plant.kind", "--plant", "str", default=PLANTS[0], choices=PLANTS, group="",
       help=_PLANTS_HELP),
    _o("base", "plant.base", "--base", "str", default="turtlebot4", choices=tuple(BASES),
       uses=_BASE, help="the base's preset (topics, message type, limits; "
                        "docs/real-robots.md)"),
    _o("physics_bases", "plant.physics_bases", "--physics-bases", "bool", default=False,
       help="with --plant base: also start physics robots that speak the base's interface "
            "(robot_sim.physics_base, --robot-model), for a run without robots"),
    _o("v_max", "plant.v_max", "--v-max", "float", unit="m/s", uses=_BRIDGES,
       metavar="M_S", default_text="the preset's or the bridge's",
       help="every bridge's speed limit"),
    _o("omega_max", "plant.omega_max", "--omega-max", "float", unit="deg/s",
       uses=_BRIDGES, metavar="DEG_S", default_text="the preset's or the bridge's",
       help="every bridge's turn rate limit"),
    _o("a_max", "plant.a_max", "--a-max", "float", unit="m/s^2", uses=_BRIDGES,
       metavar="M_S2", default_text="the preset's or the bridge's",
       help="every bridge's acceleration limit"),
    _o("alpha_max", "plant.alpha_max", "--alpha-max", "float", unit="deg/s^2",
       uses=_BRIDGES, metavar="DEG_S2", default_text="the preset's or the bridge's",
       help="every bridge's angular acceleration limit"),
    _o("params_file", "plant.params_file", "--params-file", "path", uses=_BRIDGES,
       metavar="FILE", help="a ROS 2 parameters file for the bridges (e.g. per-robot "
                            "limits under /formation/bridge_I)"),
    _o("robot_model", "plant.robot_model", "--robot-model", "str", default="p3dx",
       choices=("p3dx", "husky", "husky-imu"), uses=_BODIES_SIM,
       help="P3-DX-size two-wheel drive, the Husky of pybullet_data (wheel speeds open "
            "loop), or the Husky whose base tracks its commanded speed and turn rate "
            "(husky-imu: docs/physics.md)"),
    _o("pose", "plant.pose", "--pose", "str", default="truth", choices=("truth", "odometry"),
       uses=_BODIES_SIM,
       help="the robots' measured pose: the engine's ground truth (a motion-capture "
            "stand-in; the bridges' pose_topic) or wheel odometry (refused under the safety "
            "filter: it drifts)"),
    _o("pass_through", "plant.collide", "--pass-through", "bool", default=False,
       negated=True, uses=_BODIES_SIM,
       help="robots pass through each other instead of colliding (contacts are then not "
            "reported)"),
    _o("physics_rate", "plant.physics_rate", "--physics-rate", "float", default=240.0,
       lo=0.0, open_lo=True, unit="Hz", uses=_PHYSICS, metavar="HZ",
       help="engine steps per second"),
    _o("allow_contact", "plant.allow_contact", "--allow-contact", "bool", default=False,
       help="run on a plant with bodies although the batch simulator predicts that the "
            "robots' footprints overlap"),
    # ------------------------------------------------------------------ the safety filter
    _o("safety", "safety.enabled", "--safety", "switch", group="safety",
       default_text="on with every plant with bodies (physics, pioneer, base), off with the "
                    "kinematic simulator (the paper's reproduction is unchanged)",
       help="put every robot's learned command through the safety filter: it keeps the "
            "robots' bodies a margin apart and the command inside the base's speed and "
            "acceleration limits, and the memory learns through it"),
    _o("body", "safety.body", "--body", "str", choices=BODIES, group="safety",
       default_text="p3dx; other plants know their own",
       help="with --plant sim --safety: the body the filter keeps apart"),
    _o("safety_margin", "safety.margin", "--safety-margin", "float", lo=0.0, unit="m",
       group="safety", metavar="M",
       default_text=f"{default_margin('p3dx'):g} m; {default_margin('husky'):g} m on skid "
                    "steer, whose wheels slip: docs/safety.md",
       help="least gap between two robots' covering discs"),
    _o("safety_learning", "safety.learning", "--safety-learning", "str", choices=LEARNING,
       group="safety", default_text="damped on two wheels (robust with noisy poses), "
                                    "split on skid steer",
       help="how the memory learns where the filter changed a command: damped (takes in a "
            f"share, {DAMPING:g}, of a barrier's change and all of a limit's, and smooths "
            f"its step around the changes over {Q_SIGMA:g} s), robust (damped, and its "
            "whole step smoothed, every trial: noisy poses), applied (from the command "
            "the robot really drove), split (from it where a limit clipped the command, not "
            "at all where a barrier moved it), freeze (no learning at those samples), "
            "ignore (as if unchanged; winds up). docs/safety.md compares them"),
    _o("safety_motion", "safety.motion", "--safety-motion", "str", choices=MOTION,
       group="safety",
       default_text=f"commands up to {TOLD_UP_TO} robots, poses beyond (N (N - 1) messages "
                    "a sample) and behind bridges (pioneer, base: each on its own clock). "
                    "docs/safety.md",
       help="where a robot's filter takes the other robots' speeds from: commands (every "
            "robot tells the others the command it applies, on robot_i/applied; only its "
            "direction comes from its noisy pose) or poses (estimated from two of their "
            "poses, widened by what the scenario's noise allows: 0.12 m/s with the paper's "
            "noise, which holds robots off their own motion)"),
    _o("on_contact", "safety.on_contact", "--on-contact", "str", default="stop",
       choices=ON_CONTACT, uses=_TOUCH, group="safety",
       help="when two robots touch or one tilts past --tilt-limit: stop: stop the robots, "
            "abort the trial and run it again, at most --contact-retries times, then end "
            "the run (status 6) naming the pair; abort: stop the robots and end the run at "
            "once (status 6); continue: report it and go on. A contact in a return "
            "(physics bases) ends the run unless continue"),
    _o("contact_retries", "safety.contact_retries", "--contact-retries", "int", default=2,
       lo=0, hi=100, uses=_TOUCH, group="safety", metavar="N",
       help="with --on-contact stop: how often one trial is run again after a contact"),
    _o("tilt_limit", "safety.tilt_limit", "--tilt-limit", "float", default=10.0,
       lo=TILT_RANGE[0], hi=TILT_RANGE[1], unit="deg", uses=_TILT, group="safety",
       metavar="DEG", help="a robot tilted past this is treated as a contact"),
    # ------------------------------------------------------------------ the bridges
    _o("driver", "plant.driver", "--driver", "str", default="rosaria",
       choices=("rosaria", "p2os2", "ros2aria"), uses=_PIONEER,
       help="the robots' driver"),
    _o("driver_ns", "plant.driver_ns", "--driver-ns", "str", default=DRIVER_NS["pioneer"],
       uses=_BRIDGES, metavar="PATTERN",
       help="robot i's driver namespace, {i} replaced by the robot number (with --plant "
            f"base {DRIVER_NS['base']} unless given)"),
    _o("cmd_type", "plant.cmd_type", "--cmd-type", "str", choices=("twist", "twist_stamped"),
       uses=_BRIDGES, default_text="a --base preset's (docs/real-robots.md), Twist for a "
                                   "Pioneer driver",
       help="Twist or TwistStamped (diff_drive_controller) on the driver's cmd_vel"),
    _o("fake_drivers", "plant.fake_drivers", "--fake-drivers", "bool", default=False,
       help="with --plant pioneer: also start one fake RosAria driver per robot "
            "(robot_sim.fake_pioneer: a unicycle in wall time with odometry drift and "
            "noise), for a run without robots"),
    _o("lifecycle", "plant.lifecycle", "--lifecycle", "bool", default=False, uses=_BRIDGES,
       help="the bridges are managed (lifecycle) nodes; the launcher configures and "
            "activates each through its change_state service, and deactivates them (their "
            "bases stop) at the end"),
    _o("return_timeout", "plant.return_timeout", "--return-timeout", "float", default=60.0,
       lo=0.0, open_lo=True, unit="s", uses=_BRIDGES, metavar="S",
       help="how long a bridge drives its robot back to the initial pose between trials "
            "before it reports a timeout"),
    _o("init_memory", "run.init_memory", "--init-memory", "path", group="",
       metavar="MEMORY.npz",
       help="every robot starts from its row of this memory file (written by `formation-ilc "
            "simulate`): the sim-to-real carry-over"),
    _o("plant_nodes", "plant.nodes", "--plant-nodes", "names", default=("plant",),
       uses=_EXTERNAL, metavar="NAME", help="the node names the schedule waits for"),
    # ------------------------------------------------------------------ processes, ROS
    _o("namespace", "network.namespace", "--namespace", "str", group="processes",
       metavar="NS", default_text=NAMESPACE,
       help="ROS namespace of the whole formation; two formations in different namespaces "
            "share a ROS domain without crosstalk (/clock is remapped into the namespace)"),
    _o("container", "processes.container", "--container", "int", default=0, lo=0, hi=1024,
       group="processes", metavar="N",
       help="N robot nodes per process on one executor (0: one process per robot)"),
    _o("out", "out", "--out", "folder", group="", metavar="DIR",
       default_text="runs/SCENARIO-launch-TIME", help="output folder"),
    _o("domain_id", "network.domain_id", "--domain-id", "int", lo=0, hi=232,
       group="processes", metavar="ID",
       default_text="the caller's ROS_DOMAIN_ID if set, else a free-looking one in 30..100",
       help="ROS_DOMAIN_ID"),
    _o("discovery", "network.discovery", "--discovery", "str", default="localhost",
       choices=("localhost", "server", "inherit"), group="processes",
       help="localhost: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, and from 64 processes "
            "through a Fast DDS discovery server the launcher starts on 127.0.0.1, or with "
            "--hosts netns on the hub's address (every participant announces itself to the "
            "server only: 100 robots, one process each, start on 2 cores); server: that "
            "server for any team on this machine; inherit: keep the caller's discovery "
            "settings (multi-host runs)"),
    _o("timeout", "processes.timeout", "--timeout", "float", default=30.0, lo=0.0,
       open_lo=True, unit="s", group="processes", metavar="S",
       help="lockstep: give up when a robot has not commanded for S seconds"),
    _o("watchdog_scale", "processes.watchdog_scale", "--watchdog-scale", "float",
       default=1.0, lo=0.0, open_lo=True, group="processes", metavar="F",
       help="every bound of the liveness watchdog times F: a phase that waits past its "
            "bound (start-up, readies, samples; derived from dT and the team size) is "
            "reported, then re-run, then the run stops naming the cause "
            "(docs/reliability.md)"),
    _o("no_plots", "recording.plots", "--no-plots", "bool", default=False, negated=True,
       group="processes", help="write no figures"),
    _o("resume", None, "--resume", "path", group="", metavar="DIR",
       help="continue the interrupted run whose output folder is DIR, with its options: "
            "the robots reload their memory from DIR/state/, the trial that was running is "
            "run again, and metrics.csv goes on"),
    _o("max_restarts", "processes.max_restarts", "--max-restarts", "int", default=3,
       group="", metavar="N",
       help="restart a node process that dies at most N times (0: a dead node ends the "
            "run)"),
    _o("record", "recording.record", "--record", "file", group="", metavar="RUN.mcap",
       help="record every formation topic to this MCAP file (its own recorder process; "
            "the run starts once it listens); analyse it with `formation-ilc analyze "
            "RUN.mcap`"),
    _o("live", "live.port", "--live", "port", lo=1, hi=65535, const=LIVE_PORT, group="",
       metavar="PORT",
       help="serve the running formation to Foxglove over its WebSocket protocol on PORT "
            f"({LIVE_PORT} if not given), with the recording's topics and schemas (its own "
            "process; a slow or absent viewer never holds the run back; docs/ros-tools.md)"),
    _o("live_rate", "live.rate", "--live-rate", "float", unit="Hz", group="processes",
       metavar="HZ", default_text="30, what a screen shows",
       help="with --live: messages a second forwarded per per-sample topic (0: every "
            "message)"),
    _o("live_host", "live.host", "--live-host", "str", default="127.0.0.1",
       group="processes", metavar="ADDR",
       help="with --live: the address to serve on (127.0.0.1: this machine only; 0.0.0.0 "
            "serves every network)"),
    # ------------------------------------------------------------------ netns hosts
    _o("hosts", "network.hosts", "--hosts", "str", default="local", choices=("local", "netns"),
       group="hosts",
       help="local: every process on this machine's network; netns: each robot process in "
            "a network namespace of its own, joined by veth links to a hub namespace "
            "(leader, simulator, this launcher), DDS over UDP, unicast discovery; direct "
            "links. Needs root, iproute2 and iptables with NFQUEUE"),
    _o("net_delay_ms", "network.delay_ms", "--net-delay-ms", "float", default=0.0, unit="ms",
       group="hosts", metavar="MS",
       help="with --hosts netns: mean delay of every link between robots, per direction"),
    _o("net_jitter_ms", "network.jitter_ms", "--net-jitter-ms", "float", default=0.0,
       unit="ms", group="hosts", metavar="MS",
       help="with --hosts netns: delays uniform in delay +- jitter"),
    _o("net_loss", "network.loss", "--net-loss", "float", default=0.0, group="hosts",
       metavar="P",
       help="with --hosts netns: fraction of the packets between robots dropped, per "
            "direction"),
    _o("dds_profile", "network.dds_profile", "--dds-profile", "str",
       choices=("lossy", "none"), group="hosts",
       default_text="lossy; none through the discovery server (64 participants and more) "
                    "without --net-loss",
       help="with --hosts netns: lossy: the package's Fast DDS profile for lossy links "
            "(50 ms writer heartbeat: a lost sample is repaired within about a round "
            "trip); none: Fast DDS defaults (3 s)"),
    # ------------------------------------------------------------------ clocks
    _o("clock_offset_ms", "clocks.offset_ms", "--clock-offset-ms", "float", default=0.0,
       lo=0.0, unit="ms", group="clocks", metavar="MS",
       help="emulate robots whose clocks disagree: robot i's clock (its robot node's and "
            "its bridge's) reads an offset drawn uniformly in [-MS, MS] from the run's seed "
            "(0: the machine's clock)"),
    _o("clock_drift_ppm", "clocks.drift_ppm", "--clock-drift-ppm", "float", default=0.0,
       lo=0.0, unit="ppm", group="clocks", metavar="P",
       help="and runs a drift drawn uniformly in [-P, P] ppm fast"),
    _o("no_clock_sync", "clocks.sync", "--no-clock-sync", "bool", default=False,
       negated=True, group="clocks",
       help="switch the clock estimator off: the robots still exchange stamps and measure "
            "each link's delay, but nothing estimates or corrects the clocks (the bridges "
            "sample on their own clocks, as before the estimator)"),
    _o("clock_fallback", "clocks.fallback", "--clock-fallback", "str", default="estimate",
       choices=FALLBACKS, group="clocks",
       help="what a bridge samples on before its estimate of the leader's clock has "
            "converged: estimate: the best estimate so far; own: the robot's own clock"),
    # ------------------------------------------------------------------ security, hosts
    _o("secure", "security.keystore", "--secure", "path", group="", metavar="DIR",
       help="run every node in its SROS2 enclave of the keystore DIR (`formation-ilc "
            "keystore create DIR SCENARIO`), with DDS-Security enforced; needs the Fast DDS "
            "built by scripts/build_secure_dds.sh (docs/security.md)"),
    _o("host", None, "--host", "str", group="", metavar="NAME",
       help="with a run file whose hosts: places the members on machines: start and "
            "supervise only host NAME's members here (one launcher per machine; the host "
            "with the leader runs the checks, the monitor and the report); without it every "
            "member runs on this machine"),
    # ------------------------------------------------------------------ a stored run's own
    _o("run_id", "run.id", None, "stored",
       help="the run's identity (empty: a new one at each launch; a stored run keeps its "
            "own)"),
    _o("clock_origin_ns", "clocks.origin_ns", None, "stored", unit="ns", stored_as=int,
       help="the emulated clocks' origin (a resumed run's robots keep their clocks)"),
    _o("record_root", "recording.record_root", None, "stored", stored_as=Path,
       help="the run's first recording file (a resumed launch records a part of its own)"),
    _o("robots", "robots", None, "robots", default=(), uses=_BRIDGES,
       help="per robot I, what differs from the rest of the team: host (the machine that "
            "runs robot I's node and bridge: with no hosts: mapping, every other member runs "
            "on host 'ground'), driver_ns (robot I's driver namespace, instead of "
            "plant.driver_ns's pattern), start: [x, y, theta] [m, m, rad] (where robot I is "
            "placed: its bridge's initial pose, instead of the scenario's desired start). "
            "E.g. robots: {2: {host: r2, driver_ns: /RosAria, start: [0.0, 1.0, 0.0]}}"),
    _o("host_members", None, None, "hosts", default=(),
       help="which machine runs which members: host name -> member (process) names; "
            "empty: all on this machine"),
)

@dataclass(frozen=True)
class RobotEntry:
    """A run file's ``robots: {I: {...}}`` entry: what robot I does not share with the
    team (None: as the team)."""

    robot: int
    host: str | None = None
    driver_ns: str | None = None
    start: tuple[float, float, float] | None = None

    def as_dict(self) -> dict[str, Any]:
        """Its keys as a run file writes them (only those set)."""
        d = {"host": self.host, "driver_ns": self.driver_ns,
             "start": None if self.start is None else list(self.start)}
        return {k: v for k, v in d.items() if v is not None}


def robot_entries(value: Any) -> tuple[RobotEntry, ...]:
    """``robots:`` (robot number -> {host, driver_ns, start}) as entries, by robot;
    ValueError naming the robot and key (``2.start: ...``)."""
    if isinstance(value, tuple) and all(isinstance(e, RobotEntry) for e in value):
        return value
    if not isinstance(value, dict):
        raise ValueError(f"expected a mapping of robot numbers to {{host, driver_ns, start}}, "
                         f"got {value!r}")
    out = []
    for key, entry in value.items():
        try:
            robot = int(key)
        except (TypeError, ValueError):
            raise ValueError(f"{key}: expected a robot number") from None
        out.append(_robot_entry(robot, entry or {}))
    return tuple(sorted(out, key=lambda e: e.robot))


def _robot_entry(robot: int, entry: Any) -> RobotEntry:
    if not isinstance(entry, dict):
        raise ValueError(f"{robot}: expected a mapping of host, driver_ns, start")
    for k in entry:
        if k not in ("host", "driver_ns", "start"):
            raise ValueError(f"{robot}.{k}: unknown key (robot keys: host, driver_ns, start)")
    for k in ("host", "driver_ns"):
        if entry.get(k) is not None and not (isinstance(entry[k], str) and entry[k].strip()):
            raise ValueError(f"{robot}.{k}: expected a name, got {entry[k]!r}")
    start = entry.get("start")
    if start is not None:
        if not (isinstance(start, list | tuple) and len(start) == 3):
            raise ValueError(f"{robot}.start: expected [x, y, theta] [m, m, rad], got {start!r}")
        try:
            start = tuple(V.quantity(str(x), "rad") if i == 2 else V.float_in()(str(x))
                          for i, x in enumerate(start))
        except ValueError as exc:
            raise ValueError(f"{robot}.start: {exc}") from None
    return RobotEntry(robot, entry.get("host"), entry.get("driver_ns"), start)


#: field -> its row
BY_FIELD: dict[str, Option] = {o.field: o for o in OPTIONS}


def option(name: str) -> Option:
    """The row of field ``name``."""
    return BY_FIELD[name]


def default(name: str) -> Any:
    """The default of field ``name``: what ``LaunchOptions`` and the plant option classes
    start from."""
    return BY_FIELD[name].default
