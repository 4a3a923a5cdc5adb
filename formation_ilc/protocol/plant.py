"""The kinematic plant of every robot, free of ROS: one call per event, samples out.

The simulator node (``robot_sim.node``) is a thin ROS wrapper around ``KinematicPlant``: it
decodes messages, calls one method per event with the time it happened (``now`` [s], any
monotonic clock) and publishes the sample the plant says is due. Everything that decides
what the plant does lives here:

* the trials it runs (the leader's start and abort, taken by ``schedule.Follower``), and for
  each the plant stream of its iteration, drawn as the batch simulator draws it (initial
  shifts, input disturbances, output noises);
* eq. (1) for every robot (``kinematics.step_into``, the batch simulator's function);
* lockstep: sample t+1 once every robot has commanded sample t; sample t again when a
  command is still due RESEND_S after it went out (``resend_due``); a robot silent for
  longer than the timeout is named (``overdue``);
* realtime: one sample per wall tick, applying per robot the newest command since the
  previous tick, or holding the previous one (zero-order hold, 0 at sample 0) and counting
  the sample as missed for that robot;
* the timing figures of the diagnostics.

Another plant that keeps this schedule and timing (the rigid-body world of
``protocol.physics_plant.PhysicsPlant``) replaces the plant's own steps: ``place`` (a
trial starts at xi[:, 0]), ``move`` (sample t to t+1 under u[:, t]), ``measured`` (the
measured pose of sample t) and ``plant_report`` (what else the trial's diagnostics say).

Event order for a trial: ``on_event`` with the leader's start makes sample 0 due
(``sample()``); after publishing a sample the node calls ``sent(now)`` (the plant then waits
for commands, unless it was the trial's last sample); ``command(r, u, now)`` per command
(lockstep: True when the next sample is due); realtime ``tick(now)`` at each wall tick (True:
the next sample is due; False: no trial runs, the ticks may stop). An abort of the running
slot stops the trial.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.runconfig import RunConfig
from formation_ilc.core.clock import Rejected
from formation_ilc.core.kinematics import step_into
from formation_ilc.core.links import robot_name
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.schedule import ABORT, Follower, TrialEvent

__all__ = ["Sample", "KinematicPlant", "RESEND_S"]

#: [s] lockstep: a sample whose commands are not all in this long after it went out goes
#: out again (its /clock and every pose, bit for bit), and again every RESEND_S: a pose or
#: a shared pose lost (a flood that overran a reader's queue, a reader that matched after
#: the sample went out) is recovered in seconds, well inside the time-out. A lost command
#: is not (cmd_vel carries no label: a robot never sends one twice) and still waits for it.
#: Longer than a sample takes on a loaded machine (p99 120 ms at a load of 30 on 2 cores)
RESEND_S = 2.0


@dataclass(frozen=True)
class Sample:
    """A sample to publish: slot ``k``, sample ``t``, its label [ns], every robot's measured
    pose ``eta`` (N, 3) [m, m, rad] (a view: publish it before the next event), and whether
    it is the trial's last (t == T: the true trajectories and the report go with it)."""

    k: int
    t: int
    stamp_ns: int
    eta: NDArray[np.float64]
    last: bool


class KinematicPlant:
    """Every robot's plant for run configuration ``cfg`` (mode lockstep or realtime)."""

    def __init__(self, cfg: RunConfig):
        if cfg.mode == "wallclock":
            raise ValueError("mode wallclock is for real robots behind bridges (no /clock); "
                             "the simulator runs lockstep or realtime")
        sc = cfg.scenario
        self.cfg, self.clock = cfg, cfg.clock
        self.pb = pb = Problem.from_scenario(sc)
        self.follower = Follower(cfg.run_id, clock=cfg.clock)
        self.realtime = cfg.mode == "realtime"
        n, n_t = pb.n, pb.samples
        self.n, self.T = n, n_t
        #: the order to send the robots' poses of a sample in: first the robots whose pose
        #: another robot waits for (the start of a lockstep sample's longest chains: pose,
        #: shared pose, command), then the others
        senders = {int(j) for j in pb.src.ravel() if j >= 0}
        self.send_order = ([r for r in range(n) if r in senders]
                           + [r for r in range(n) if r not in senders])
        self.xi = np.zeros((n, n_t + 1, 3))      # true states of the trial
        self.eta = np.zeros((n, n_t + 1, 3))     # measured outputs (true + noise)
        self.u = np.zeros((n, n_t, 2))           # applied inputs
        self.dist = np.zeros((n, n_t, 2))
        self.noise = np.zeros((n, n_t + 1, 3))
        self.t = -1
        self.pending: set[int] = set()   # robots whose command for sample t is still due
        self.in_trial = False
        self.wait_start = 0.0            # [s] sample t went out
        self.last_send = 0.0             # [s] sample t went out last (lockstep re-sends)
        self.resends = 0
        self.trial_t0 = 0.0
        self.missed: Counter[str] = Counter()
        #: realtime: the misses by sample of the trial (where in a trial they fall)
        self.missed_at: Counter[int] = Counter()
        self.latency: list[float] = []   # [s] sample published -> every command in
        self.trial_time = 0.0            # [s] time inside trials
        self.samples_done = 0
        self.u_now = np.zeros((n, 2))     # realtime: newest command of each robot
        self.fresh = np.zeros(n, dtype=bool)
        self.arrival: list[float] = []    # [s] realtime: tick -> each command's arrival
        self.tick_lag: list[float] = []   # [s] realtime: tick after its due time
        self.tick_due = 0.0
        self.last_in = 0.0
        self.late_cmds = 0                # realtime: commands after the trial's last tick
        self.superseded = 0               # realtime: commands replaced before their tick
        if self.realtime:
            self.missed.update({robot_name(r + 1): 0 for r in range(n)})

    @property
    def k(self) -> int:
        """Slot of the current (or last) trial."""
        return self.follower.slot

    @property
    def iteration(self) -> int:
        """Iteration of the current (or last) trial."""
        return self.follower.trial

    # ------------------------------------------------------------------ the schedule
    def on_event(self, ev: TrialEvent, now: float) -> TrialEvent | None:
        """The leader's event: the start or abort taken (a start makes sample 0 due), or
        None (nothing to do); Rejected for a start the plant must not obey
        (``schedule.Follower``)."""
        taken = self.follower.take(ev, idle=not self.in_trial)
        if taken is None or taken.event == ABORT:
            if taken is not None and taken.slot == self.k:
                self.in_trial = False
                self.pending = set()
            return taken
        pb = self.pb
        # the plant stream of the iteration, as the batch simulator draws it
        shift, self.dist, self.noise = self.cfg.scenario.uncertainty.draw_plant(
            self.cfg.scenario.seed, taken.trial, pb.n, pb.samples)
        self.xi[:, 0] = pb.eta_d[:, 0] + shift
        self.place()
        self.u[:] = 0.0
        self.t = 0
        self.in_trial = True
        self.trial_t0 = now
        if self.realtime:
            self.u_now[:] = 0.0
            self.fresh[:] = False
            self.tick_due = now + pb.dt
        self._measure(now)
        return taken

    def said_ready(self) -> None:
        self.follower.said_ready()

    # ------------------------------------------------------------------ samples
    def _measure(self, now: float) -> None:
        """Sample t is due: its measured outputs; at sample T the trial is over."""
        t = self.t
        self.eta[:, t] = self.measured(t)
        if t == self.T:
            self.in_trial = False
            self.trial_time += now - self.trial_t0
            self.samples_done += self.T

    def sample(self) -> Sample:
        """The sample due now (after an event that said one is)."""
        t = self.t
        return Sample(self.k, t, self.clock.stamp_ns(self.k, t), self.eta[:, t], t == self.T)

    def stamps(self) -> list[int]:
        """Labels [ns] of samples 0..T of the current slot (the true trajectories')."""
        return [self.clock.stamp_ns(self.k, s) for s in range(self.T + 1)]

    def sent(self, now: float) -> None:
        """Sample t (not the last) went out at ``now``: every robot's command is due."""
        self.pending = set(range(self.n))
        self.wait_start = self.last_send = now

    def resend_due(self, now: float) -> bool:
        """Lockstep: whether sample t must go out again now (RESEND_S since it last went
        out, and a command still due); counted in ``resends``. The time-out still counts
        from the first send."""
        if self.realtime or not self.in_trial or not self.pending \
                or now - self.last_send < RESEND_S:
            return False
        self.last_send = now
        self.resends += 1
        return True

    def _step(self, now: float) -> None:
        t = self.t
        self.move(t)
        self.t = t + 1
        self._measure(now)

    # ------------------------------------------------------------------ the plant itself
    def place(self) -> None:
        """A trial starts at xi[:, 0] (the kinematic state is xi itself)."""

    def move(self, t: int) -> None:
        """xi[:, t + 1] from xi[:, t] under u[:, t] and the input disturbance (eq. 1)."""
        step_into(self.xi[:, t], self.u[:, t], self.dist[:, t], self.pb.dt, self.xi[:, t + 1])

    def measured(self, t: int) -> NDArray[np.float64]:
        """The measured pose of sample t, (N, 3): the true state plus the output noise."""
        return self.xi[:, t] + self.noise[:, t]

    def plant_report(self) -> dict[str, Any]:
        """What else a trial's diagnostics say (another plant's)."""
        return {}

    # ------------------------------------------------------------------ commands
    def command(self, r: int, u: NDArray[np.float64], now: float) -> bool:
        """Robot ``r``'s (0-based) command (v [m/s], omega [rad/s]) arrived at ``now``.
        Lockstep: True when it was the last one due (the next sample is due); Rejected
        (out_of_order) outside a trial or for a second command of the sample. Realtime:
        kept for the next tick (a newer one replaces it); never True."""
        if self.realtime:
            self._command_realtime(r, u, now)
            return False
        if not self.in_trial or r not in self.pending:
            raise Rejected("out_of_order", f"a second command for sample {self.t}")
        self.u[r, self.t] = u
        self.pending.discard(r)
        if self.pending:
            return False
        self.latency.append(now - self.wait_start)
        self._step(now)
        return True

    def _command_realtime(self, r: int, u: NDArray[np.float64], now: float) -> None:
        if not self.in_trial:
            self.late_cmds += 1  # for the trial's last sample, after its last tick
            return
        if self.fresh[r]:
            self.superseded += 1
        else:
            self.arrival.append(now - self.wait_start)
            self.pending.discard(r)
            if not self.pending:
                self.last_in = now - self.wait_start
        self.u_now[r] = u
        self.fresh[r] = True

    def tick(self, now: float) -> bool:
        """Realtime: the wall tick of sample t+1 fired at ``now``. True: that sample is
        due; False: no trial runs (the ticks may stop)."""
        if not self.in_trial:
            return False
        self.tick_lag.append(now - self.tick_due)
        self.tick_due += self.pb.dt
        t = self.t
        for r in np.flatnonzero(~self.fresh):
            self.missed[robot_name(int(r) + 1)] += 1
            self.missed_at[t] += 1
        self.u[:, t] = self.u_now  # newest command, or the held one for a robot that missed
        self.fresh[:] = False
        if not self.pending:
            self.latency.append(self.last_in)
        self._step(now)
        return True

    def overdue(self, now: float, timeout: float) -> list[int]:
        """Lockstep: the robots (0-based) whose command for sample t is more than
        ``timeout`` [s] late at ``now`` (empty if none)."""
        if self.in_trial and self.pending and now - self.wait_start > timeout:
            return sorted(self.pending)
        return []

    # ------------------------------------------------------------------ report
    def report(self) -> dict[str, Any]:
        """The trial's diagnostics: trial, slot, mode, missed samples per robot (realtime;
        ``missed_at``: the samples of a trial with most misses, at most 10, and how many),
        timing (``timing``)."""
        out = {"trial": self.iteration, "slot": self.k, "mode": self.cfg.mode,
               "missed": dict(self.missed), "resends": self.resends,
               "timing": self.timing(), **self.plant_report()}
        if self.realtime:  # the samples with most misses (at most 10): where in a trial
            out["missed_at"] = {str(t): c for t, c in self.missed_at.most_common(10)}
        return out

    def timing(self) -> dict[str, Any]:
        """Samples, seconds inside trials, and the command latency [ms] (lockstep: sample
        published -> every command in; realtime: tick -> each command's arrival, with the
        all-in latency and how late the ticks fired)."""
        lat = np.array(self.arrival if self.realtime else self.latency) * 1e3
        if lat.size == 0:
            lat = np.full(1, np.nan)
        tim = {"samples": self.samples_done, "seconds": self.trial_time,
               "samples_per_s": self.samples_done / max(self.trial_time, 1e-9),
               "p50_ms": float(np.percentile(lat, 50)),
               "p90_ms": float(np.percentile(lat, 90)),
               "p99_ms": float(np.percentile(lat, 99)),
               "max_ms": float(lat.max())}
        if self.realtime:
            all_in = np.array(self.latency or [np.nan]) * 1e3
            lag = np.array(self.tick_lag or [np.nan]) * 1e3
            tim.update({"commands": len(self.arrival),
                        "missed_total": int(sum(self.missed.values())),
                        "all_in_p50_ms": float(np.percentile(all_in, 50)),
                        "all_in_p99_ms": float(np.percentile(all_in, 99)),
                        "tick_lag_p50_ms": float(np.percentile(lag, 50)),
                        "tick_lag_p99_ms": float(np.percentile(lag, 99)),
                        "tick_lag_max_ms": float(lag.max()),
                        "late_commands": self.late_cmds, "superseded": self.superseded})
        return tim
