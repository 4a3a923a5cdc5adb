"""One robot as a pure learner: its memory, its trial, its links, one call per event.

The robot node (``formation_ilc.nodes.robot``) is a thin ROS wrapper around this class: it
decodes messages into (label, output) pairs, calls one method per event and publishes what
comes back. Everything that decides what the robot does lives here, with no ROS import:

* the label-to-sample mapping of its own poses (``SampleClock``), new trials, missed
  samples and the zero-order hold of what the plant applied when the robot did not command;
* each link's inbox (``LinkInbox``: emulated ticks or direct poses), eq. (11) from Rt and
  St, eq. (10) gating (in ``law.command``), and the per-link delay histograms; in lockstep
  with direct links the leader link is the robot's own sample (``leader_in_step``);
* the learning memory and the trial-end learning from the neighbours' whole trajectories
  (``law.learn``, the same function the batch simulator calls);
* with a safety filter (``core.safety``), the other robots' poses it hears
  (``on_team_pose``; ``protocol.hearing``, the part that hears the team), the filter
  between the law's command and the plant (``safety.filter_command``, the batch
  simulator's), and learning through it
  (``through.learn_base``): in lockstep it waits for every robot's pose of its sample, as
  the batch simulator filters with them.

Event order for trial k: ``on_pose`` per sample (the robot's own measured pose, whose label
is its clock Rt); link inputs (``on_link_pose`` or ``on_link_tick``) in any order; when
``can_command()`` (or at a realtime deadline) ``command()``; after sample T,
``finish_trial()`` gives the trajectory to share; ``on_trajectory`` per neighbour; when
``learned`` reaches k the robot is ready for trial k+1.

Trials are named by their slot on the label grid (``formation_ilc.protocol.schedule``): ``k``,
``finished`` and ``learned`` are slots, ``iterations`` counts the trials learned. A slot the
leader aborts (``abort``) is forgotten, and undone if this robot already learned from it;
every label of it is refused afterwards (stale). ``state()`` / ``restore()`` carry the
learning state through a crash (``formation_ilc.store.robotstate``).

The window of what a robot accepts (every other input is Rejected with its reason, and
moves nothing): its own poses of the current trial, and of the next trial once it has
learned the current one (it is then ready for it: the leader cannot have started a later
one); link inputs of those trials, in lockstep labelled at most ``LINK_LOOKAHEAD`` sample
after its own current sample (a neighbour's pose t+1 may overtake the robot's own pose
t+1; t+2 cannot exist before the robot commanded t+1); whole-trial trajectories of those
trials. In realtime a robot whose process stalled may see its links run any number of
samples ahead of its own poses, so there only the trial window applies.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.clock import Malformed, Rejected, SampleClock, TrialWindow
from formation_ilc.core.delays import measure_delay_ns
from formation_ilc.core.law import command, learn
from formation_ilc.core.links import LEADER, Delivery, LinkInbox, link_name, robot_name
from formation_ilc.core.safety import (
    CHANGED,
    CHANGED_BARRIER,
    CHANGED_LIMITS,
    INFEASIBLE,
    SafetySpec,
)
from formation_ilc.core.through import after_learning, learn_base
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.hearing import TeamHearing
from formation_ilc.store.robotstate import RobotState

__all__ = ["PoseEvent", "RobotLearner", "LINK_LOOKAHEAD"]

#: lockstep: how many samples after its own current sample a link input may be labelled
LINK_LOOKAHEAD = 1
#: what the leader link "delivers" in step (``leader_in_step``): eq. (9) uses its label only
_UNUSED_POSE = np.zeros(3)
_UNUSED_POSE.flags.writeable = False


@dataclass(frozen=True)
class PoseEvent:
    """What an own pose means: its trial and sample, whether it starts a trial, and
    whether it ends one (sample T: nothing to command, the trajectory is complete)."""

    trial: int
    sample: int
    new_trial: bool
    last: bool


class RobotLearner(TeamHearing):
    """Robot ``index`` (0-based) of problem ``pb``.

    realtime : the plant does not wait for commands (samples may be missed and held).
    direct : links are direct (newest pose with St <= Rt) rather than emulated ticks.
    memory : initial learning memory, shape (T, 2) [m/s, rad/s]; default 0 (u_0 = 0).
    leader_in_step : lockstep with direct links (``RunConfig.leader_in_step``): at each own
        pose the leader link delivers that pose's label (St = Rt, what the robot would
        wait for; eq. 9 reads the leader link's label only); no reference is taken.
    safety : the safety filter between the law's command and the plant (None: none).
    """

    def __init__(self, pb: Problem, index: int, clock: SampleClock, *, realtime: bool = False,
                 direct: bool = False, memory: NDArray[np.float64] | None = None,
                 leader_in_step: bool = False, safety: SafetySpec | None = None):
        if leader_in_step and (realtime or not direct):
            raise ValueError("leader_in_step is for lockstep with direct links")
        if not 0 <= index < pb.n:
            raise ValueError(f"robot {index + 1}: the scenario has robots 1..{pb.n}")
        self.pb, self.i, self.clock = pb, index, clock
        self.realtime, self.direct = realtime, direct
        self.name = robot_name(index + 1)
        n_t, n_l = pb.samples, pb.src.shape[1]
        self.T = n_t
        self.sl = slice(index, index + 1)
        #: sender name -> link slot ell (-1 for the leader)
        self.slots: dict[str, int] = {robot_name(int(j) + 1): ell
                                      for ell, j in enumerate(pb.src[index]) if j >= 0}
        self.sees_leader = bool(pb.leader[index] != 0.0)
        if self.sees_leader:
            self.slots[LEADER] = -1
        self.inbox = {s: LinkInbox(s, clock, direct) for s in self.slots}
        #: the leader link taken from the robot's own samples (None: from messages)
        self.leader_box = self.inbox[LEADER] if leader_in_step and self.sees_leader else None
        self.neighbours = [s for s in self.slots if s != LEADER]
        self.memory = np.zeros((1, n_t, 2))
        if memory is not None:
            m = np.asarray(memory, dtype=float)
            if m.shape != (n_t, 2):
                raise ValueError(f"{self.name}: memory must have shape {(n_t, 2)}, "
                                 f"got {m.shape}")
            self.memory[0] = m
        self.next_memory = np.zeros_like(self.memory)
        self.prev_memory = self.memory.copy()   # before the last learning step (rollback)
        self.iterations = 0     # trials learned
        self.prev_iterations = 0
        self.prev_learned = -1
        self.floor = -1         # labels of slots <= floor are refused (aborted or learned)
        self.restored = False   # restored from a state file, no trial entered since
        #: learning steps undone by aborts, by slot: (memory, iterations) after the step and
        #: the learned slot before it; a step the leader says stands is taken back (redo)
        self.undone: dict[int, tuple[NDArray[np.float64], int, int]] = {}
        self.applied = np.zeros((1, n_t, 2))
        self.eta = np.zeros((1, n_t + 1, 3))
        self.have = np.zeros(n_t + 1, dtype=bool)
        self.nb_eta = np.zeros((1, n_l, 3))
        self.nb_s = np.full((1, n_l), -1, dtype=np.int64)
        self.lead_s = np.full(1, -1, dtype=np.int64)
        self.nb_full = np.zeros((1, n_l, n_t + 1, 3))
        self.u = np.zeros((1, 2))
        self.k = -1            # current trial
        self.t = -1            # current sample (own pose received)
        self.rt_ns = 0         # Rt: the robot's clock at the current sample
        self.commanded = True
        self.finished = -1     # last trial whose own trajectory is complete
        self.learned = -1      # last trial learned from
        self.trajs: dict[int, dict[int, NDArray[np.float64]]] = {}
        self.delays: dict[str, Counter[int]] = {s: Counter() for s in self.slots}
        self.missed = 0
        self.commands = 0
        self.safety = safety
        if safety is not None:
            self._init_hearing(pb.n, n_t, index, safety)

    # ------------------------------------------------------------------ own poses
    def expected_heading(self, sender: str, label_ns: int) -> float | None:
        """The desired heading of ``sender`` at ``label_ns``'s sample: where to unwrap its
        measured heading (None for the leader, whose heading the law does not use).
        Rejected if the label is off the grid or the sender is no in-link."""
        _, s = self.clock.decode(label_ns)
        if sender == self.name:
            return float(self.pb.eta_d[self.i, s, 2])
        ell = self._slot(sender)
        return None if ell < 0 else float(self.pb.eta_d[self.pb.src[self.i, ell], s, 2])

    def expected_team_heading(self, j: int, label_ns: int) -> float:
        """The desired heading of robot ``j`` (0-based) at ``label_ns``'s sample: where to
        unwrap its measured heading heard for the safety filter (the filter takes cos and
        sin only). Rejected if the label is off the grid or ``j`` is no robot."""
        if not 0 <= j < self.pb.n:
            raise Rejected("unexpected", f"team pose of robot index {j}")
        _, s = self.clock.decode(label_ns)
        return float(self.pb.eta_d[j, s, 2])

    def _slot(self, sender: str) -> int:
        ell = self.slots.get(sender)
        if ell is None:
            raise Malformed(f"{sender} is not an in-link of {self.name}")
        return ell

    def is_repeat(self, label_ns: int) -> bool:
        """Lockstep: whether a pose labelled ``label_ns`` is the current sample again (not
        the trial's last): the plant re-sent it because a command of it is still due, so
        the shared pose this robot sent for it may have been lost
        (``protocol.plant.RESEND_S``). The pose itself is refused all the same (``on_pose``:
        stale)."""
        if self.realtime or self.t < 0 or self.t >= self.T:
            return False
        try:
            return self.clock.decode(label_ns) == (self.k, self.t)
        except Rejected:
            return False

    def on_pose(self, label_ns: int, eta: NDArray[np.float64]) -> PoseEvent:
        """The robot's own measured pose, labelled with its clock Rt. Rejected: a sample
        not after the current one (stale), and in lockstep a skipped sample
        (out_of_order). In realtime a skipped or uncommanded sample is counted in
        ``missed`` and recorded as held (what the plant applied)."""
        k, s = self.clock.decode(label_ns)
        if k <= self.floor or (k == self.k and s <= self.t):
            raise Rejected("stale", f"sample ({k}, {s}) after ({self.k}, {self.t})")
        new = self._window(k, "own pose")
        if not self.realtime:
            if new and s != 0:
                raise Rejected("out_of_order", f"trial {k} starts at sample {s}")
            if not new and s != self.t + 1:
                raise Rejected("out_of_order", f"sample {s} while {self.t + 1} is due")
        if new:
            self._new_trial(k)
        else:
            if not self.commanded:  # realtime: the pose t+1 overtook our command for t
                self.missed += 1
                self._hold(self.t)
            for skipped in range(self.t + 1, s):  # realtime: poses that never came
                self.missed += 1
                self._hold(skipped)
        self.t = s
        self.rt_ns = label_ns
        self.eta[0, s] = eta
        self.have[s] = True
        last = s == self.T
        self.commanded = last
        if self.leader_box is not None and not last:
            # the law reads only the label's sample of the leader link: the pose is unused
            self.leader_box.offer(label_ns, _UNUSED_POSE, k)
        return PoseEvent(k, s, new, last)

    def _window(self, k: int, what: str) -> bool:
        """Whether trial ``k`` is the next trial (True) or the current one; Rejected
        outside the window: the next trial is open once the current one is learned or
        aborted. A robot just restored from its state file cannot know which slot the
        leader runs next (it may have aborted one meanwhile): it takes the first later
        trial it sees."""
        if self.restored and k > self.k:
            return True
        return TrialWindow(self.k, self.learned >= self.k or self.floor >= self.k).check(
            k, what)

    def _lookahead(self, label_ns: int, what: str) -> None:
        """Rejected if a link input's trial is outside the window, or (lockstep, future)
        it is labelled beyond the robot's own next sample."""
        k, _ = self.clock.decode(label_ns)
        self._window(k, what)
        if self.realtime:
            return
        if self.k >= 0 and k == self.k:
            limit = self.clock.stamp_ns(self.k, self.t + LINK_LOOKAHEAD)
        else:  # the next trial (open): from its start
            limit = self.clock.stamp_ns(k, LINK_LOOKAHEAD - 1)
        if label_ns > limit:
            raise Rejected("future", f"{what} labelled {label_ns} ns, beyond {limit} ns "
                                     f"(the robot is at sample ({self.k}, {self.t}))")

    def _new_trial(self, k: int) -> None:
        self.restored = False
        self.k = k
        self.t = -1
        self.have[:] = False
        self.applied[:] = 0.0
        if self.safety is not None:
            self.nominal[:] = 0.0
            self.flags[:] = 0
            self.pose_age[:] = 0.0
            self.untold[:] = 0
            self._team_trial(k)

    def _hold(self, t: int) -> None:
        """Record what the plant applied at a sample the robot did not command: the
        previous command (zero-order hold; 0 at sample 0)."""
        if t < self.T:
            self.applied[0, t] = self.applied[0, t - 1] if t > 0 else 0.0
            if self.safety is not None:  # nothing of it was the law's to learn from
                self.nominal[0, t] = self.applied[0, t]

    # ------------------------------------------------------------------ links
    def on_link_pose(self, sender: str, label_ns: int, eta: NDArray[np.float64]) -> None:
        """Direct link: ``sender``'s shared pose (or the leader's reference) arrived."""
        self._fresh(label_ns)
        box = self._inbox(sender)
        self._lookahead(label_ns, f"{sender}'s pose")
        box.offer(label_ns, eta, max(self.k, 0))

    def _fresh(self, label_ns: int) -> None:
        k, _ = self.clock.decode(label_ns)
        if k <= self.floor:
            raise Rejected("stale", f"label of slot {k}, aborted or learned (<= {self.floor})")

    def on_link_tick(self, sender: str, tick_ns: int,
                     pose: tuple[int, NDArray[np.float64]] | None) -> None:
        """Emulated link: at tick ``tick_ns`` the link from ``sender`` delivered ``pose``
        (label, output), or nothing."""
        self._fresh(tick_ns)
        d = None if pose is None else Delivery(sender, pose[0], pose[1])
        box = self._inbox(sender)
        self._lookahead(tick_ns, f"{sender}'s link tick")
        box.offer_tick(tick_ns, d, max(self.k, 0))

    def _inbox(self, sender: str) -> LinkInbox:
        self._slot(sender)
        return self.inbox[sender]

    def can_command(self) -> bool:
        """A sample is due and every link has what it will deliver for it (lockstep with a
        safety filter: and every other robot's pose of the sample is in)."""
        if self.commanded or not all(b.has(self.rt_ns) for b in self.inbox.values()):
            return False
        if self.safety is None or self.realtime:
            return True
        if self.team_k != self.k or not self.team_have[:, self.t].all():
            return False
        # told commands: every other robot's of the sample before (a trial starts at rest)
        return (not self.safety.commands or self.t == 0
                or bool(self.told_have[:, self.t - 1].all()))

    def command(self) -> NDArray[np.float64]:
        """u(t) = (v [m/s], omega [rad/s]) of the current sample from what the links
        deliver now (eq. 11 per delivery; a link with nothing contributes nothing)."""
        if self.commanded:
            raise RuntimeError(f"{self.name}: no sample to command")
        t, rt = self.t, self.rt_ns
        self.nb_s[0] = -1
        self.lead_s[0] = -1
        for sender, box in self.inbox.items():
            d = box.take(rt)
            if d is None:
                continue
            tau = measure_delay_ns(rt, d.label_ns, self.clock.dt_ns)  # eq. (11)
            s = t - tau
            ell = self.slots[sender]
            if ell < 0:
                self.lead_s[0] = s
            else:
                self.nb_eta[0, ell] = d.eta
                self.nb_s[0, ell] = s
            self.delays[sender][tau] += 1
        pb, sl = self.pb, self.sl
        command(t, pb.law, self.memory[:, t], self.eta, pb.eta_d[sl], self.nb_eta, self.nb_s,
                pb.src[sl], pb.weight[sl], pb.eta_d, self.lead_s, pb.leader[sl],
                pb.gain_prime[sl], pb.heading, self.u)
        if self.safety is not None:
            self._filter(t)
        self.applied[0, t] = self.u[0]
        self.commanded = True
        self.commands += 1
        return self.u[0]

    # ------------------------------------------------------------------ trial end
    def finish_trial(self) -> tuple[int, NDArray[np.float64]]:
        """(trial, own measured trajectory (T+1, 3)) once sample T is in; a sample that
        never came is held from the one before it (realtime)."""
        for s in range(self.T + 1):
            if not self.have[s]:
                self.eta[0, s] = self.eta[0, max(s - 1, 0)]
        for box in self.inbox.values():  # deliveries for samples already commanded
            box.forget(self.rt_ns)
        self.finished = self.k
        if self.safety is not None:
            f = self.flags[0]
            old = self.pose_age > 0.0
            acted = (f & (CHANGED_BARRIER | INFEASIBLE)) != 0
            # a sample older than the one before: later than a wall-clock team hears its
            # peers (bridges tick on their own clocks; a pose of the sample before is usual)
            later = self.pose_age > 1.5 * self.pb.dt
            counts = {"changed": int(np.count_nonzero(f & CHANGED)),
                      "limits": int(np.count_nonzero(f & CHANGED_LIMITS)),
                      "barrier": int(np.count_nonzero(f & CHANGED_BARRIER)),
                      "infeasible": int(np.count_nonzero(f & INFEASIBLE)),
                      # samples with a pose of another robot in range not of the sample
                      # itself (the filter widens its distance by its age), and those a
                      # barrier changed or flagged on a pose older than the sample before
                      "stale": int(np.count_nonzero(old)),
                      "late": int(np.count_nonzero(later & acted)),
                      # samples filtered against a robot whose told command was not in
                      "untold": int(np.count_nonzero(self.untold)),
                      # poses (this robot's and the others') that missed their box: a
                      # robot that did not move as it told (``core.estimate``)
                      "box_missed": self.box_missed}
            self.box_missed = 0
            self.filtered = {"slot": self.k, **counts, "late_ms": int(round(
                1000.0 * float(self.pose_age[later & acted].max(initial=0.0))))}
            self.filtered_total.update(counts)
        return self.k, self.eta[0]

    def trajectory_stamps(self, trial: int) -> list[int]:
        return [self.clock.stamp_ns(trial, s) for s in range(self.T + 1)]

    def on_trajectory(self, sender: str, stamps: NDArray[np.int64],
                      eta: NDArray[np.float64]) -> bool:
        """A neighbour's whole-trial trajectory. Returns True when the robot learned from
        its trial (then it is ready for the next one). Rejected: not samples 0..T of one
        trial (malformed), a trial already learned (stale)."""
        if sender not in self.neighbours:
            raise Malformed(f"{sender} is not an in-link of {self.name}")
        if len(stamps) != self.T + 1:
            raise Malformed(f"trajectory has {len(stamps)} samples, expected "
                                        f"{self.T + 1}")
        k, s0 = self.clock.decode(int(stamps[0]))
        if s0 != 0 or any(int(x) != self.clock.stamp_ns(k, s) for s, x in enumerate(stamps)):
            raise Malformed("trajectory stamps are not samples 0..T of one trial")
        if k <= self.learned or k <= self.floor:
            raise Rejected("stale", f"trajectory of trial {k}, already learned or aborted")
        self._window(k, f"{sender}'s trajectory")
        self.trajs.setdefault(k, {})[self.slots[sender]] = np.array(eta, dtype=float)
        return self.try_learn()

    def try_learn(self) -> bool:
        """Learn from the finished trial once every neighbour's trajectory is in."""
        k = self.finished
        have = self.trajs.get(k, {})
        if k < 0 or self.learned >= k or len(have) < len(self.neighbours):
            return False
        pb, sl = self.pb, self.sl
        for ell, eta in have.items():
            self.nb_full[0, ell] = eta
        self.prev_memory[:] = self.memory
        self.prev_iterations, self.prev_learned = self.iterations, self.learned
        start = self.memory
        if self.safety is not None:  # learning through the filter (core.safety)
            learn_base(self.safety_mode, self.memory, self.nominal, self.applied, self.flags,
                       self.base)
            start = self.base
        learn(pb.law, pb.memory, start, self.applied, self.eta, pb.eta_d[sl],
              self.nb_full, pb.src[sl], pb.weight[sl], pb.eta_d, pb.leader[sl], pb.gain[sl],
              pb.heading, self.next_memory)
        if self.safety is not None:
            after_learning(self.safety_mode, pb.dt, self.memory, self.flags,
                           self.next_memory)
        self.memory, self.next_memory = self.next_memory, self.memory
        self.learned = k
        self.iterations += 1
        for old in [x for x in self.trajs if x <= k]:
            del self.trajs[old]
        return True

    # ------------------------------------------------------------------ faults
    def abort(self, slot: int) -> bool:
        """The leader aborted ``slot``: forget it (and undo the learning step if this robot
        already learned from it). Returns True if the memory was rolled back."""
        if slot <= self.floor and slot != self.learned:
            return False
        rolled = False
        if self.learned == slot:
            self.undone = {slot: (self.memory.copy(), self.iterations, self.prev_learned),
                           **{q: v for q, v in self.undone.items() if q < slot}}
            self.memory[:] = self.prev_memory
            self.iterations, self.learned = self.prev_iterations, self.prev_learned
            rolled = True
        self.floor = max(self.floor, slot)
        if self.k <= slot:
            self.k, self.t, self.commanded = slot, self.T, True
        if self.finished >= slot:
            self.finished = self.learned
        self.trajs = {k: v for k, v in self.trajs.items() if k > slot}
        for box in self.inbox.values():
            box.clear()
        return rolled

    def redo(self, slot: int) -> bool:
        """The leader says ``slot`` is committed (an abort's ``kept``): if this robot undid
        its learning step from it (on an abort the leader did not send) and has learned
        nothing since, the step is taken back. Returns True if it was."""
        got = self.undone.get(slot)
        if got is None or self.learned != got[2]:
            return False
        memory, iterations, before = got
        self.prev_memory[:] = self.memory
        self.prev_iterations, self.prev_learned = self.iterations, self.learned
        self.memory[:] = memory
        self.iterations, self.learned = iterations, slot
        self.finished = max(self.finished, slot)
        del self.undone[slot]
        return True

    def done_with(self, slot: int) -> bool:
        """Whether the robot holds nothing more of ``slot`` (-1: none): it has learned from
        it, or the slot was aborted. Until then a start of a later slot is not the leader's
        (``schedule.Follower``: the robot is not idle)."""
        return slot <= self.learned or slot <= self.floor

    def state(self) -> RobotState:
        """What a restarted robot needs (``formation_ilc.store.robotstate``)."""
        return RobotState(self.memory[0].copy(), self.iterations, self.learned,
                          self.prev_memory[0].copy(), self.prev_iterations, self.prev_learned)

    def restore(self, st: RobotState) -> None:
        """Continue from a saved state: every label of a slot up to the learned one is
        stale; the next trial the leader starts is the robot's next."""
        self.memory[0] = st.memory
        self.prev_memory[0] = st.prev_memory
        self.iterations, self.learned = st.iterations, st.slot
        self.prev_iterations, self.prev_learned = st.prev_iterations, st.prev_slot
        self.floor = self.finished = st.slot
        self.k, self.t, self.commanded = st.slot, self.T, True
        self.restored = True

    def diagnostics(self) -> dict[str, object]:
        """Counters for the diagnostics topic: commands, missed samples, per link the
        histogram of measured delays (eq. 11) keyed by the sender, and (emulated links) how
        many deliveries came after their sample was commanded (``unused``)."""
        d: dict[str, object] = {
            "node": self.name, "trial": self.iterations - 1, "slot": self.learned,
            "commands": self.commands,
            "missed": self.missed,
            "delays": {s: {str(t): c for t, c in sorted(h.items())}
                       for s, h in self.delays.items()}}
        if not self.direct:
            d["unused"] = {s: b.unused for s, b in self.inbox.items()}
        if self.safety is not None:
            # the commands the filter changed: in the last trial finished (its slot), and
            # in all trials of this process
            d["filter"] = dict(self.filtered)
            d["filter_total"] = dict(self.filtered_total)
        return d

    def link_names(self) -> list[str]:
        return [link_name(s, self.name) for s in self.slots]
