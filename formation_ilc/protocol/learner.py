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
  (``on_team_pose``), the filter between the law's command and the plant
  (``safety.filter_command``, the batch simulator's), and learning through it
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

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.clock import Malformed, Rejected, SampleClock, TrialWindow
from formation_ilc.core.delays import measure_delay_ns
from formation_ilc.core.estimate import BOX, box_centre, box_error, box_start, box_step
from formation_ilc.core.law import command, learn
from formation_ilc.core.links import LEADER, Delivery, LinkInbox, link_name, robot_name
from formation_ilc.core.safety import (
    CHANGED,
    CHANGED_BARRIER,
    CHANGED_LIMITS,
    INFEASIBLE,
    OTHER_FIELDS,
    SafetySpec,
    filter_command,
    motion,
    told,
)
from formation_ilc.core.through import after_learning, learn_base, learning_code
from formation_ilc.model.simulate import Problem
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


#: from this many robots heard, those too far for the filter are dropped before it runs
#: (``RobotLearner._near``): below it numpy's cost per call is more than it saves
NEAR_FROM = 16


class RobotLearner:
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
            n = pb.n
            self.safety_params = safety.params()
            self.safety_mode = learning_code(safety.learning)
            self.team_k = -1                            # the trial team_eta holds
            self.team_eta = np.zeros((n, n_t + 1, 3))   # other robots' poses heard
            self.team_have = np.zeros((n, n_t + 1), dtype=bool)
            self.team_last = np.full(n, -1, dtype=np.int64)  # newest sample heard
            #: the commands the other robots told they applied over each sample
            #: (``safety.commands``), and which are in
            self.told_u = np.zeros((n, n_t, 2))
            self.told_have = np.zeros((n, n_t), dtype=bool)
            self.nominal = np.zeros((1, n_t, 2))        # the law's commands
            self.flags = np.zeros((1, n_t), dtype=np.int64)
            #: per sample, the age [s] of the oldest pose of another robot in range (0:
            #: every pose of the sample itself)
            self.pose_age = np.zeros(n_t)
            #: per sample, how many robots in range were filtered against without their
            #: told command (``safety.commands``: its speed estimated from its poses)
            self.untold = np.zeros(n_t, dtype=np.int64)
            self.base = np.zeros((1, n_t, 2))
            self.others = np.zeros((n, OTHER_FIELDS))
            self.ages = np.zeros(n)
            self.out = np.zeros(2)
            #: each robot's box of positions (``core.estimate``; its own in row ``index``)
            #: where commands are told, the sample it is of (-1: none yet this trial), and
            #: how many poses missed their box
            self.boxes = np.zeros((n, BOX))
            self.box_s = np.full(n, -1, dtype=np.int64)
            self.box_missed = 0
            self._other_idx = np.array([j for j in range(n) if j != index], dtype=np.int64)
            #: the commands the filter changed in the last trial finished, and in all
            self.filtered: dict[str, int] = {}
            self.filtered_total = Counter({"changed": 0, "limits": 0, "barrier": 0,
                                           "infeasible": 0, "stale": 0, "late": 0,
                                           "untold": 0, "box_missed": 0})

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

    # ------------------------------------------------------------------ safety filter
    def _team_trial(self, k: int) -> None:
        """The team's poses now held are of trial ``k`` (a later one starts afresh); the
        robot's own poses count as heard."""
        if self.team_k != k:
            self.team_k = k
            self.team_have[:] = False
            self.team_have[self.i] = True
            self.team_last[:] = -1
            self.told_have[:] = False
            self.told_have[self.i] = True
            self.box_s[:] = -1

    def on_team_pose(self, j: int, label_ns: int, eta: NDArray[np.float64]) -> None:
        """Robot ``j``'s (0-based) pose labelled ``label_ns``, for the safety filter.
        Rejected: no filter or the robot itself (unexpected), a slot aborted or learned
        (stale), outside the robot's window (its trial, the next once learned), a trial
        older than the poses held (stale), a sample heard already (duplicate)."""
        if self.safety is None or j == self.i or not 0 <= j < self.pb.n:
            raise Rejected("unexpected", f"team pose of robot index {j}")
        self._fresh(label_ns)
        k, s = self.clock.decode(label_ns)
        self._window(k, "team pose")
        if k < self.team_k:
            raise Rejected("stale", f"team pose of trial {k} after trial {self.team_k}")
        self._team_trial(k)
        if self.team_have[j, s]:
            raise Rejected("duplicate", f"robot {j + 1}'s pose of sample {s}")
        self.team_eta[j, s] = eta
        self.team_have[j, s] = True
        self.team_last[j] = max(self.team_last[j], s)

    def on_told(self, j: int, label_ns: int, v: float, w: float) -> None:
        """Robot ``j``'s (0-based) command (v [m/s], omega [rad/s]) applied over the sample
        labelled ``label_ns``, as it told it (``safety.commands``), for the safety filter.
        Rejected: no filter taking told commands, or the robot itself (unexpected); a
        command outside the base's limits, which no robot of the run applies (malformed);
        and as ``on_team_pose`` for its label (stale, outside the window, duplicate)."""
        sp = self.safety
        if sp is None or not sp.commands or j == self.i or not 0 <= j < self.pb.n:
            raise Rejected("unexpected", f"told command of robot index {j}")
        self._fresh(label_ns)
        k, s = self.clock.decode(label_ns)
        self._window(k, "told command")
        if s >= self.T:
            raise Rejected("unexpected", f"robot {j + 1}'s command for sample {s}: a trial "
                                         f"commands samples 0..{self.T - 1}")
        lim = sp.limits
        if not (abs(v) <= lim.v_max * (1.0 + 1e-9) and abs(w) <= lim.omega_max * (1.0 + 1e-9)):
            raise Rejected("malformed", f"robot {j + 1}'s command ({v!r}, {w!r}) outside the "
                                        f"limits")
        if k < self.team_k:
            raise Rejected("stale", f"told command of trial {k} after trial {self.team_k}")
        self._team_trial(k)
        if self.told_have[j, s]:
            raise Rejected("duplicate", f"robot {j + 1}'s command of sample {s}")
        self.told_u[j, s, 0] = v
        self.told_u[j, s, 1] = w
        self.told_have[j, s] = True

    def on_team_poses(self, labels: NDArray[np.int64], fields: NDArray[np.float64]) -> bool:
        """Every robot's pose of one sample at once (``labels`` (n,), the seven doubles of
        each pose (n, 7): ``protocol.wire.read_pose_block`` of the plant's ``team/poses``,
        robot j in row j; this robot's own row is not read). True: all taken, exactly as
        ``on_team_pose`` takes them one by one. False: nothing taken, because something in
        the message needs a verdict per pose (an invalid pose, a label off the common
        sample, a duplicate): ``on_team_pose`` then takes or refuses each. The checks are
        those of ``on_team_pose`` and ``wire.world_eta``, on arrays; the headings are
        computed with the same float operations, so the filter sees the same bits."""
        if self.safety is None or len(labels) != self.pb.n or self.pb.n < 2:
            return False
        idx = self._other_idx
        lab = labels[idx]
        first = int(lab[0])
        if not (lab == first).all():
            return False
        try:
            self._fresh(first)
            k, s = self.clock.decode(first)
            self._window(k, "team pose")
        except Rejected:
            return False
        if k < self.team_k or (k == self.team_k and self.team_have[idx, s].any()):
            return False
        f = fields[idx]
        q = f[:, 3:]
        with np.errstate(invalid="ignore", over="ignore"):
            norm = np.sqrt((q * q).sum(axis=1))
        if not (np.isfinite(f[:, :2]).all() and np.isfinite(q).all()
                and (np.abs(norm - 1.0) <= 1e-6).all()
                and (np.abs(q[:, :2]) <= 1e-6).all()):
            return False
        # wire.heading_from_quaternion, element by element (math.atan2: numpy's may differ
        # in the last bit)
        ref = self.pb.eta_d[idx, s, 2]
        th = 2.0 * np.array([math.atan2(z, w) for z, w in zip(q[:, 2].tolist(),
                                                              q[:, 3].tolist(),
                                                              strict=True)])
        d = th - ref
        th = ref + (d - 2.0 * math.pi * np.ceil((d - math.pi) / (2.0 * math.pi)))
        self._team_trial(k)
        self.team_eta[idx, s, :2] = f[:, :2]
        self.team_eta[idx, s, 2] = th
        self.team_have[idx, s] = True
        self.team_last[idx] = np.maximum(self.team_last[idx], s)
        return True

    def _filter(self, t: int) -> None:
        """The safety filter on this sample's command ``self.u`` (in place): with the
        newest pose heard of every other robot (in lockstep, the sample's own), its
        motion from the pose ``window`` samples before, and its age."""
        sp = self.safety
        assert sp is not None
        m = self._heard(t, sp.window) if self.team_k == self.k else 0
        prev = self.applied[0, t - 1] if t > 0 else (0.0, 0.0)
        own = self.eta[0, t]
        x, y = float(own[0]), float(own[1])
        if sp.commands:
            x, y = self._own_box(t)
            if m:  # the pair's positions off together: robot j's box and this robot's own
                told_rows = self.others[:m, 6] > 0.0
                self.others[:m, 7][told_rows] += box_error(self.boxes, self.i)
        if m >= NEAR_FROM:
            m = self._near(m, x, y)
        self.nominal[0, t] = self.u[0]
        self.flags[0, t] = filter_command(
            float(self.u[0, 0]), float(self.u[0, 1]), x, y,
            float(own[2]), float(prev[0]), float(prev[1]), self.others, self.ages, m,
            self.safety_params, self.out)
        if m:
            self.pose_age[t] = float(self.ages[:m].max())
            if sp.commands:
                self.untold[t] = int(np.count_nonzero(self.others[:m, 6] == 0.0))
        self.u[0] = self.out

    def _near(self, m: int, x: float, y: float) -> int:
        """Keep, in order, those of the first ``m`` robots heard that ``filter_command``
        does not skip for their distance (its own test, on arrays: the same bits); returns
        how many. A robot of a large team hears every other, and in plain Python each one
        costs the filter a few operations even when far."""
        o = self.others[:m]
        gx = x - o[:, 0]
        gy = y - o[:, 1]
        radius = float(self.safety_params[3])
        keep = ~(gx * gx + gy * gy > radius * radius)
        k = int(keep.sum())
        if k < m:
            self.others[:k] = o[keep]
            self.ages[:k] = self.ages[:m][keep]
        return k

    def _heard(self, t: int, window: int) -> int:
        """Fill ``others`` and ``ages`` with what this robot heard of the others up to
        sample t (``core.safety.motion``'s reading, as the batch simulator's
        ``filter_team``); returns how many."""
        dt = self.pb.dt
        idx = self._other_idx
        last = np.minimum(self.team_last[idx], t)
        back = np.maximum(last - window, 0) if window > 0 else last
        have = self.team_have
        if (last >= 0).all() and have[idx, last].all() and have[idx, back].all():
            # every pose at hand (lockstep): all at once
            e1, e0 = self.team_eta[idx, last], self.team_eta[idx, back]
            m = len(idx)
            o = self.others
            o[:m, :3] = e1
            span = (last - back) * dt
            with np.errstate(invalid="ignore", divide="ignore"):
                d = e1 - e0
                d[:, 2] -= 2.0 * np.pi * np.floor((d[:, 2] + np.pi) / (2.0 * np.pi))
                o[:m, 3:6] = np.where(span[:, None] > 0, d / span[:, None], 0.0)
                o[:m, 6] = 0.0
            self.ages[:m] = (t - last) * dt
            o[:m, 7] = self.safety_params[17]  # PARAMS "pose_error": raw poses
            if self.safety is not None and self.safety.commands:
                for mm in range(m):
                    self._told(mm, int(idx[mm]), int(last[mm]))
            return m
        m = 0
        for j in idx:
            row = have[j]
            sj = int(self.team_last[j])
            while sj > t or (sj >= 0 and not row[sj]):  # realtime: newest up to t
                sj -= 1
            if sj < 0:
                continue  # never heard in this trial: nothing to keep away from
            sb = max(0, sj - window) if window > 0 else sj
            while sb < sj and not row[sb]:  # the nearest heard after it
                sb += 1
            e1, e0 = self.team_eta[j, sj], self.team_eta[j, sb]
            self.others[m, :3] = e1
            self.others[m, 7] = self.safety_params[17]  # PARAMS "pose_error": raw poses
            motion(e1[0], e1[1], e1[2], e0[0], e0[1], e0[2], (sj - sb) * dt, self.others, m)
            if self.safety is not None and self.safety.commands:
                self._told(m, int(j), sj)
            self.ages[m] = (t - sj) * dt
            m += 1
        return m

    def _told(self, m: int, j: int, s: int) -> None:
        """Row ``m`` of ``others`` (robot ``j``'s pose of sample ``s``): its motion from the
        command it told it applied over the sample before (``core.safety.told``, as the
        batch simulator's ``filter_team``; at rest at a trial's start), and its position
        from its box (``core.estimate``), where that is in; else the estimate from its
        poses stays, and the raw pose."""
        if s == 0:
            told(float(self.others[m, 2]), 0.0, 0.0, self.others, m)
        elif self.told_have[j, s - 1]:
            told(float(self.others[m, 2]), float(self.told_u[j, s - 1, 0]),
                 float(self.told_u[j, s - 1, 1]), self.others, m)
        else:
            return
        self._box_to(j, s, self.team_eta[j], self.told_u[j], self.team_have[j],
                     self.told_have[j])
        self.others[m, 0], self.others[m, 1] = box_centre(self.boxes, j)
        self.others[m, 7] = box_error(self.boxes, j)

    def _own_box(self, t: int) -> tuple[float, float]:
        """This robot's own box moved on to sample t (its measured poses, the commands it
        applied), as every other robot keeps it; its centre."""
        if t == 0 or self.box_s[self.i] > t:
            self.box_s[self.i] = -1
        self._box_to(self.i, t, self.eta[0], self.applied[0], self.have, None)
        return box_centre(self.boxes, self.i)

    def _box_to(self, j: int, s: int, eta: NDArray[np.float64], cmd: NDArray[np.float64],
                have: NDArray[np.bool_], cmd_have: NDArray[np.bool_] | None) -> None:
        """Robot ``j``'s box moved on, sample by sample, to its pose of sample ``s``
        (``eta`` its poses, ``cmd`` its commands over each sample, with which of them are
        in): as the batch simulator's ``core.safety.team_boxes``. Where a pose or a
        command of the way is missing, the box starts afresh from the pose of ``s``."""
        sp = self.safety_params
        noise, process, heading, dt = (float(sp[18]), float(sp[19]), float(sp[20]),
                                       float(sp[8]))
        k = int(self.box_s[j])
        if k < 0 or k > s:
            box_start(self.boxes, j, float(eta[s, 0]), float(eta[s, 1]), noise)
            k = s
        while k < s:
            if not (have[k] and have[k + 1] and (cmd_have is None or cmd_have[k])):
                box_start(self.boxes, j, float(eta[s, 0]), float(eta[s, 1]), noise)
                break
            if not box_step(self.boxes, j, float(eta[k, 2]), float(cmd[k, 0]),
                            float(cmd[k, 1]), dt, float(eta[k + 1, 0]), float(eta[k + 1, 1]),
                            noise, process, heading):
                self.box_missed += 1
            k += 1
        self.box_s[j] = s

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
