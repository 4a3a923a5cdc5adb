"""A robot's learner hearing its team, and its safety filter (``RobotLearner``'s part).

With a safety filter (``core.safety``), a robot hears the other robots' poses
(``on_team_pose``, or a sample's at once: ``on_team_poses``) and the commands they tell
(``on_told``), and filters the law's command with what it heard (``_filter``): the newest
pose of every other robot, its motion from its poses or the command it told, its box of
positions (``core.estimate``), as the batch simulator's ``filter_team`` reads them.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.clock import Rejected, SampleClock
from formation_ilc.core.estimate import BOX, box_centre, box_error, box_start, box_step
from formation_ilc.core.safety import OTHER_FIELDS, SafetySpec, filter_command, motion, told
from formation_ilc.core.through import learning_code
from formation_ilc.model.simulate import Problem

__all__ = ["TeamHearing", "NEAR_FROM"]

#: from this many robots heard, those too far for the filter are dropped before it runs
#: (``RobotLearner._near``): below it numpy's cost per call is more than it saves
NEAR_FROM = 16


class TeamHearing:
    """The part of ``protocol.learner.RobotLearner`` that hears the team and filters."""

    # what the learner holds and does (``RobotLearner``)
    pb: Problem
    i: int
    clock: SampleClock
    T: int
    k: int
    t: int
    eta: NDArray[np.float64]
    applied: NDArray[np.float64]
    have: NDArray[np.bool_]
    u: NDArray[np.float64]
    safety: SafetySpec | None
    _fresh: Callable[[int], None]
    _window: Callable[[int, str], bool]

    def _init_hearing(self, n: int, n_t: int, index: int, safety: SafetySpec) -> None:
        """What hearing the team and filtering hold: ``n`` robots, ``n_t`` samples."""
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
        self._other_list = [j for j in range(n) if j != index]
        #: the commands the filter changed in the last trial finished, and in all
        self.filtered: dict[str, int] = {}
        self.filtered_total = Counter({"changed": 0, "limits": 0, "barrier": 0,
                                       "infeasible": 0, "stale": 0, "late": 0,
                                       "untold": 0, "box_missed": 0})

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
        # Python numbers (``tolist``): each element read of an array costs ~0.2 us
        v_prev, w_prev = self.applied[0, t - 1].tolist() if t > 0 else (0.0, 0.0)
        x, y, th = self.eta[0, t].tolist()
        v_n, w_n = self.u[0].tolist()
        if sp.commands:
            x, y = self._own_box(t)
            if m:  # the pair's positions off together: robot j's box and this robot's own
                told_rows = self.others[:m, 6] > 0.0
                self.others[:m, 7][told_rows] += box_error(self.boxes, self.i)
        if m >= NEAR_FROM:
            m = self._near(m, x, y)
        self.nominal[0, t] = self.u[0]
        self.flags[0, t] = filter_command(v_n, w_n, x, y, th, v_prev, w_prev, self.others,
                                          self.ages, m, self.safety_params, self.out)
        if m:
            self.pose_age[t] = max(self.ages[:m].tolist())
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
        have = self.team_have
        if len(idx) >= NEAR_FROM:  # a large team: every pose at hand (lockstep) at once
            last = np.minimum(self.team_last[idx], t)
            back = np.maximum(last - window, 0) if window > 0 else last
            if (last >= 0).all() and have[idx, last].all() and have[idx, back].all():
                return self._heard_all(t, idx, last, back)
        m = 0
        pose_error = float(self.safety_params[17])  # PARAMS "pose_error": raw poses
        commands = self.safety is not None and self.safety.commands
        o = self.others
        # robot by robot, as Python numbers (below NEAR_FROM robots numpy's cost per call
        # is more than its loop saves)
        for j, sj in zip(self._other_list, self.team_last[idx].tolist(), strict=True):
            row = have[j]
            sj = min(sj, t)
            while sj >= 0 and not row[sj]:  # realtime: newest up to t
                sj -= 1
            if sj < 0:
                continue  # never heard in this trial: nothing to keep away from
            sb = max(0, sj - window) if window > 0 else sj
            while sb < sj and not row[sb]:  # the nearest heard after it
                sb += 1
            x1, y1, th1 = self.team_eta[j, sj].tolist()
            x0, y0, th0 = self.team_eta[j, sb].tolist()
            o[m, 0] = x1
            o[m, 1] = y1
            o[m, 2] = th1
            o[m, 7] = pose_error
            motion(x1, y1, th1, x0, y0, th0, (sj - sb) * dt, o, m)
            if commands:
                self._told(m, j, sj)
            self.ages[m] = (t - sj) * dt
            m += 1
        return m

    def _heard_all(self, t: int, idx: NDArray[np.int64], last: NDArray[np.int64],
                   back: NDArray[np.int64]) -> int:
        """``_heard`` of a large team with every pose at hand (lockstep), on arrays: the
        newest pose of each robot in ``idx`` (sample ``last``) and its motion from the pose
        of sample ``back``."""
        dt = self.pb.dt
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
