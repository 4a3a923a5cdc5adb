"""The options of ``formation-ilc launch``, as a command-line parser.

The parser has no defaults (``without_defaults``): what it parses holds only the options
given, and each overrides its key of a run file (``formation_ilc.cli.runfile``); every
default is ``formation_ilc.plan.options.LaunchOptions``'.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from formation_ilc.cli.options import (
    add_run_options,
    float_range,
    int_range,
    nonneg_float,
    out_dir_arg,
    output_file_arg,
    positive_float,
)
from formation_ilc.config.plants import PLANT_TABLE, PLANTS
from formation_ilc.config.runconfig import MODES
from formation_ilc.core.links import LINK_MODES
from formation_ilc.protocol.physics_plant import TILT_RANGE

__all__ = ["add_arguments", "launch_parser", "without_defaults", "arrange_help", "COMMON"]

#: the options most runs need: ``launch --help`` shows them first, on one screen; the rest
#: sit under headings for special runs (a run file documents every key)
COMMON = ("help", "scenario", "trials", "seed", "no_noise", "no_delay", "plant", "mode",
          "links", "out", "record", "live", "resume", "init_memory", "max_restarts", "secure",
          "host")
#: the special runs' headings of the options that are not COMMON, by option
SPECIAL = {
    "the run's reference and learning law": ("law", "memory", "headings", "time_scale"),
    "the plant's details (--plant)": (
        "base", "physics_bases", "v_max", "omega_max", "a_max", "alpha_max", "params_file",
        "robot_model", "pose", "pass_through", "physics_rate", "allow_contact", "driver",
        "driver_ns", "cmd_type", "fake_drivers", "lifecycle", "return_timeout",
        "plant_nodes"),
    "processes, ROS and the live view": (
        "namespace", "container", "domain_id", "discovery", "timeout", "watchdog_scale",
        "no_plots", "live_rate", "live_host"),
}


def without_defaults(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``p`` with no option defaults: what it parses holds only the options given, which
    override a run file's keys; every default is ``plan.options.LaunchOptions``'."""
    for action in p._actions:
        if action.dest != "help":
            action.default = argparse.SUPPRESS
    return p


def arrange_help(p: argparse.ArgumentParser) -> None:
    """``--help`` with the COMMON options first and every other under a heading for
    special runs (the option groups of the safety filter, the clocks and netns hosts
    among them)."""
    main = p._optionals
    specials = []
    for title, dests in SPECIAL.items():
        g = p.add_argument_group(f"for special runs: {title}")
        moved = [a for a in main._group_actions if a.dest in dests]
        for a in moved:
            main._group_actions.remove(a)
        g._group_actions.extend(moved)
        specials.append(g)
    main.title = "the options most runs need (the rest are for special runs, below)"
    for g in p._action_groups:
        special = (g.title or "").startswith("for special")
        if g not in (main, p._positionals, *specials) and not special:
            g.title = f"for special runs: {g.title}"
    rest = [g for g in p._action_groups if g not in (main, p._positionals)]
    p._action_groups[:] = [p._positionals, main, *rest]


def launch_parser() -> argparse.ArgumentParser:
    """The parser of ``formation-ilc launch``'s options (without defaults)."""
    from formation_ilc.cli.options import OneLineParser

    p = OneLineParser(prog="formation-ilc launch", add_help=False)
    add_arguments(p)
    return without_defaults(p)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", nargs="?",
                   help="built-in scenario name (formation-ilc scenarios), a scenario YAML "
                        "file, or a run file (formation-ilc run-file: every option of the "
                        "run; an option given here overrides its key); not with --resume")
    add_run_options(p, trials=20, shape=True)
    p.add_argument("--mode", choices=MODES, default=None,
                   help="lockstep (default with the simulator): the simulator waits for every "
                        "robot (as fast as the processes allow, deterministic); realtime: the "
                        "simulator ticks on the wall clock at dT; wallclock (default and "
                        "required with --plant pioneer): no /clock, the trials run on the "
                        "machines' synchronised wall clocks")
    p.add_argument("--links", choices=LINK_MODES, default=None,
                   help="emulated (default): a link emulator process puts the scenario's "
                        "delays on the robot-to-robot links, in simulated time (a lockstep "
                        "run equals `simulate`); direct: each robot subscribes to its "
                        "neighbours, as on robots, and the delays are the network's (a "
                        "lockstep run equals `simulate --no-delay`; the default and required "
                        "with --plant pioneer)")
    p.add_argument("--plant", choices=PLANTS, default=PLANTS[0],
                   help="; ".join(f"{row.name}{' (default)' if row.name == PLANTS[0] else ''}: "
                                  f"{row.help}" for row in PLANT_TABLE))
    add_plant_arguments(p)
    p.add_argument("--driver", choices=("rosaria", "p2os2", "ros2aria"), default="rosaria",
                   help="with --plant pioneer: the robots' driver (default rosaria)")
    p.add_argument("--driver-ns", default="/pioneer_{i}", metavar="PATTERN",
                   help="with --plant pioneer: robot i's driver namespace, {i} replaced by "
                        "the robot number (default /pioneer_{i}; with --plant base "
                        "/base_{i})")
    p.add_argument("--cmd-type", choices=("twist", "twist_stamped"), default=None,
                   help="Twist or TwistStamped (diff_drive_controller) on the driver's "
                        "cmd_vel; default: a --base preset's (docs/real-robots.md), Twist "
                        "for a Pioneer driver")
    p.add_argument("--fake-drivers", action="store_true",
                   help="with --plant pioneer: also start one fake RosAria driver per robot "
                        "(robot_sim.fake_pioneer: a unicycle in wall time with odometry "
                        "drift and noise), for a run without robots")
    p.add_argument("--lifecycle", action="store_true",
                   help="with --plant pioneer or base: the bridges are managed (lifecycle) "
                        "nodes; the launcher configures and activates each through its "
                        "change_state service, and deactivates them (their bases stop) at "
                        "the end")
    p.add_argument("--return-timeout", type=positive_float, default=60.0, metavar="S",
                   help="with --plant pioneer: how long a bridge drives its robot back to the "
                        "initial pose between trials before it reports a timeout")
    p.add_argument("--init-memory", type=Path, metavar="MEMORY.npz",
                   help="every robot starts from its row of this memory file (written by "
                        "`formation-ilc simulate`): the sim-to-real carry-over")
    p.add_argument("--plant-nodes", nargs="+", default=["plant"], metavar="NAME",
                   help="with --plant external: the node names the schedule waits for "
                        "(default: plant)")
    p.add_argument("--namespace", default=None, metavar="NS",
                   help="ROS namespace of the whole formation (default /formation); two "
                        "formations in different namespaces share a ROS domain without "
                        "crosstalk (/clock is remapped into the namespace)")
    p.add_argument("--container", type=int_range(0, 1024), default=0, metavar="N",
                   help="N robot nodes per process on one executor (0: one process per "
                        "robot, the default)")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: runs/SCENARIO-launch-TIME)")
    p.add_argument("--domain-id", type=int_range(0, 232), metavar="ID",
                   help="ROS_DOMAIN_ID (default: the caller's ROS_DOMAIN_ID if set, else a "
                        "free-looking one in 30..100)")
    p.add_argument("--discovery", choices=("localhost", "server", "inherit"),
                   default="localhost",
                   help="localhost (default): ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, and "
                        "from 64 processes through a Fast DDS discovery server the launcher "
                        "starts on 127.0.0.1, or with --hosts netns on the hub's address "
                        "(every participant announces itself to the server only: 100 robots, "
                        "one process each, start on 2 cores); "
                        "server: that server for any team on this machine; inherit: keep "
                        "the caller's discovery settings (multi-host runs)")
    p.add_argument("--timeout", type=positive_float, default=30.0, metavar="S",
                   help="lockstep: give up when a robot has not commanded for S seconds")
    p.add_argument("--watchdog-scale", type=positive_float, default=1.0, metavar="F",
                   help="every bound of the liveness watchdog times F (default 1): a phase "
                        "that waits past its bound (start-up, readies, samples; derived from "
                        "dT and the team size) is reported, then re-run, then the run stops "
                        "naming the cause (docs/reliability.md)")
    p.add_argument("--no-plots", action="store_true", help="write no figures")
    p.add_argument("--resume", type=Path, metavar="DIR",
                   help="continue the interrupted run whose output folder is DIR, with its "
                        "options: the robots reload their memory from DIR/state/, the trial "
                        "that was running is run again, and metrics.csv goes on")
    p.add_argument("--max-restarts", type=int, default=3, metavar="N",
                   help="restart a node process that dies at most N times (default 3; 0: "
                        "a dead node ends the run)")
    p.add_argument("--record", type=output_file_arg, metavar="RUN.mcap",
                   help="record every formation topic to this MCAP file (its own recorder "
                        "process; the run starts once it listens); analyse it with "
                        "`formation-ilc analyze RUN.mcap`")
    p.add_argument("--live", type=int_range(1, 65535), nargs="?", const=8765, default=None,
                   metavar="PORT",
                   help="serve the running formation to Foxglove over its WebSocket protocol "
                        "on PORT (default 8765), with the recording's topics and schemas "
                        "(its own process; a slow or absent viewer never holds the run back; "
                        "docs/ros-tools.md)")
    p.add_argument("--live-rate", type=float, default=None, metavar="HZ",
                   help="with --live: messages a second forwarded per per-sample topic "
                        "(default 30, what a screen shows; 0: every message)")
    p.add_argument("--live-host", default="127.0.0.1", metavar="ADDR",
                   help="with --live: the address to serve on (default 127.0.0.1, this "
                        "machine only; 0.0.0.0 serves every network)")
    add_host_arguments(p)
    add_clock_arguments(p)
    p.add_argument("--secure", type=Path, default=None, metavar="DIR",
                   help="run every node in its SROS2 enclave of the keystore DIR (`formation-"
                        "ilc keystore create DIR SCENARIO`), with DDS-Security enforced; "
                        "needs the Fast DDS built by scripts/build_secure_dds.sh "
                        "(docs/security.md)")
    p.add_argument("--host", metavar="NAME",
                   help="with a run file whose hosts: places the members on machines: start "
                        "and supervise only host NAME's members here (one launcher per "
                        "machine; the host with the leader runs the checks, the monitor and "
                        "the report); without it every member runs on this machine")
    arrange_help(p)


def add_plant_arguments(p: argparse.ArgumentParser) -> None:
    """The options of the physics plant and of the bridges' bases and limits."""
    from formation_ilc.config.bases import BASES

    p.add_argument("--base", choices=tuple(BASES), default="turtlebot4",
                   help="with --plant base: the base's preset (topics, message type, limits; "
                        "docs/real-robots.md), default turtlebot4")
    p.add_argument("--physics-bases", action="store_true",
                   help="with --plant base: also start physics robots that speak the base's "
                        "interface (robot_sim.physics_base, --robot-model), for a run without "
                        "robots")
    for name, unit in (("v-max", "m/s"), ("omega-max", "deg/s"), ("a-max", "m/s^2"),
                       ("alpha-max", "deg/s^2")):
        p.add_argument(f"--{name}", type=float, default=0.0,
                       metavar=unit.upper().replace("/", "_").replace("^", ""),
                       help=f"with --plant pioneer or base: every bridge's {name.split('-')[0]}"
                            f" limit [{unit}] (default: the preset's or the bridge's)")
    p.add_argument("--params-file", type=Path, metavar="FILE",
                   help="with --plant pioneer or base: a ROS 2 parameters file for the "
                        "bridges (e.g. per-robot limits under /formation/bridge_I)")
    p.add_argument("--robot-model", choices=("p3dx", "husky", "husky-imu"), default="p3dx",
                   help="with --plant physics (or --physics-bases): P3-DX-size two-wheel "
                        "drive (default), the Husky of pybullet_data (wheel speeds open "
                        "loop), or the Husky whose base tracks its commanded speed and turn "
                        "rate (husky-imu: docs/physics.md)")
    p.add_argument("--pose", choices=("truth", "odometry"), default="truth",
                   help="with --plant physics or --physics-bases: the robots' measured pose, "
                        "the engine's ground truth (a motion-capture stand-in, default; the "
                        "bridges' pose_topic) or wheel odometry (refused under the safety "
                        "filter: it drifts)")
    p.add_argument("--pass-through", action="store_true",
                   help="with --plant physics: robots pass through each other instead of "
                        "colliding (contacts are then not reported)")
    p.add_argument("--physics-rate", type=positive_float, default=240.0, metavar="HZ",
                   help="with --plant physics: engine steps per second (default 240)")
    p.add_argument("--allow-contact", action="store_true",
                   help="run on a plant with bodies although the batch simulator predicts "
                        "that the robots' footprints overlap")
    add_safety_arguments(p)


def add_safety_arguments(p: argparse.ArgumentParser) -> None:
    """The safety filter's options (docs/safety.md)."""
    from formation_ilc.config.safety import BODIES, MOTION, TOLD_UP_TO
    from formation_ilc.core.safety import LEARNING
    from formation_ilc.core.through import DAMPING, Q_SIGMA

    g = p.add_argument_group("the safety filter (docs/safety.md)")
    g.add_argument("--safety", action=argparse.BooleanOptionalAction, default=None,
                   help="put every robot's learned command through the safety filter: it "
                        "keeps the robots' bodies a margin apart and the command inside the "
                        "base's speed and acceleration limits, and the memory learns "
                        "through it. Default: on with every plant with bodies (physics, "
                        "pioneer, base), off with the kinematic simulator (the paper's "
                        "reproduction is unchanged)")
    g.add_argument("--body", choices=BODIES, default=None,
                   help="with --plant sim --safety: the body the filter keeps apart "
                        "(default p3dx); other plants know their own")
    g.add_argument("--safety-margin", type=nonneg_float, default=None, metavar="M",
                   help="least gap [m] between two robots' covering discs (default 0.1; "
                        "0.25 on skid steer, whose wheels slip: docs/safety.md)")
    g.add_argument("--safety-learning", choices=LEARNING, default=None,
                   help="how the memory learns where the filter changed a command: damped "
                        f"(takes in a share, {DAMPING:g}, of a barrier's change and all "
                        "of a limit's, and smooths its step around the changes over "
                        f"{Q_SIGMA:g} s; the default on two wheels), applied (from the command "
                        "the robot really drove), split (from it where a limit clipped the "
                        "command, not at all where a barrier moved it; the default on skid "
                        "steer: husky, jackal), freeze (no learning at those samples), "
                        "ignore (as if unchanged; winds up). docs/safety.md compares them")
    g.add_argument("--safety-motion", choices=MOTION, default=None,
                   help="where a robot's filter takes the other robots' speeds from: "
                        "commands (every robot tells the others the command it applies, on "
                        "robot_i/applied; only its direction comes from its noisy pose) or "
                        "poses (estimated from two of their poses, widened by what the "
                        "scenario's noise allows: 0.12 m/s with the paper's noise, which "
                        "holds robots off their own motion). Default: commands up to "
                        f"{TOLD_UP_TO} robots, poses beyond (N (N - 1) messages a sample) and "
                        "behind bridges (pioneer, base: each on its own clock). "
                        "docs/safety.md")
    g.add_argument("--on-contact", choices=("stop", "abort", "continue"), default="stop",
                   help="with --plant physics or --physics-bases, when two robots touch "
                        "or one tilts past --tilt-limit: stop (default): stop the robots, "
                        "abort the trial and run it again, at most --contact-retries times, "
                        "then end the run (status 6) naming the pair; abort: stop the robots "
                        "and end the run at once (status 6); continue: report it and go on. "
                        "A contact in a return (physics bases) ends the run unless continue")
    g.add_argument("--contact-retries", type=int_range(0, 100), default=2, metavar="N",
                   help="with --on-contact stop: how often one trial is run again after a "
                        "contact (default 2)")
    g.add_argument("--tilt-limit", type=float_range(*TILT_RANGE, unit="deg"), default=10.0,
                   metavar="DEG",
                   help="with --plant physics or --physics-bases: a robot tilted past this "
                        "[deg] is treated as a contact (default 10)")


# --------------------------------------------------------------------------- clocks
def add_clock_arguments(p: argparse.ArgumentParser) -> None:
    from formation_ilc.config.clocks import FALLBACKS

    g = p.add_argument_group("robots' clocks: realtime and wallclock runs "
                             "(docs/distributed-stack.md, docs/real-robots.md)")
    g.add_argument("--clock-offset-ms", type=nonneg_float, default=0.0, metavar="MS",
                   help="emulate robots whose clocks disagree: robot i's clock (its robot "
                        "node's and its bridge's) reads an offset drawn uniformly in "
                        "[-MS, MS] from the run's seed (default 0: the machine's clock)")
    g.add_argument("--clock-drift-ppm", type=nonneg_float, default=0.0, metavar="P",
                   help="and runs a drift drawn uniformly in [-P, P] ppm fast (default 0)")
    g.add_argument("--no-clock-sync", action="store_true",
                   help="switch the clock estimator off: the robots still exchange stamps "
                        "and measure each link's delay, but nothing estimates or corrects "
                        "the clocks (the bridges sample on their own clocks, as before the "
                        "estimator)")
    g.add_argument("--clock-fallback", choices=FALLBACKS, default="estimate",
                   help="what a bridge samples on before its estimate of the leader's "
                        "clock has converged: estimate (default): the best estimate so "
                        "far; own: the robot's own clock")


# --------------------------------------------------------------------------- separate hosts
def add_host_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("robots on separate hosts, one machine (root; "
                             "docs/lossy-links.md)")
    g.add_argument("--hosts", choices=("local", "netns"), default="local",
                   help="local (default): every process on this machine's network; netns: "
                        "each robot process in a network namespace of its own, joined by "
                        "veth links to a hub namespace (leader, simulator, this launcher), "
                        "DDS over UDP, unicast discovery; direct links. Needs root, iproute2 "
                        "and iptables with NFQUEUE")
    g.add_argument("--net-delay-ms", type=float, default=0.0, metavar="MS",
                   help="with --hosts netns: mean delay of every link between robots, per "
                        "direction (default 0)")
    g.add_argument("--net-jitter-ms", type=float, default=0.0, metavar="MS",
                   help="with --hosts netns: delays uniform in delay +- jitter (default 0)")
    g.add_argument("--net-loss", type=float, default=0.0, metavar="P",
                   help="with --hosts netns: fraction of the packets between robots "
                        "dropped, per direction (default 0)")
    g.add_argument("--dds-profile", choices=("lossy", "none"), default=None,
                   help="with --hosts netns: lossy (default): the package's Fast DDS profile "
                        "for lossy links (50 ms writer heartbeat: a lost sample is repaired "
                        "within about a round trip); none: Fast DDS defaults (3 s), the "
                        "default through the discovery server (64 participants and more) "
                        "without --net-loss")
