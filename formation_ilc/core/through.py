"""Learning through the safety filter: what the memory learns where the filter changed a command.

Learning through the filter (``LEARNING``): the memory must not wind up where the filter
overrode the learned command. ``learn_base`` gives the memory the learning step starts
from, ``freeze_flagged`` restores it where nothing may be learned (``after_learning``
runs it and the Q-filter below after the step):

* ``applied``: m + (u_applied - u_nominal) at every changed sample, so the memory learns
  from the command the robot really drove (the anti-windup of ILC with input saturation);
* ``freeze``: the old memory at every changed sample;
* ``split``: ``applied`` where only a limit clipped the command (a saturation, the same
  from trial to trial: anti-windup is right), ``freeze`` where a barrier moved it (another
  robot was in the way: a state of this trial, not of the task);
* ``ignore``: learns as if nothing had been changed (winds up; for comparison);
* ``damped``: ``applied`` where only a limit clipped the command, m + DAMPING
  (u_applied - u_nominal) where a barrier moved it: a sixth or so of ``applied``'s anti-
  windup. ``applied`` carries every trim a barrier made into the next trial, where it
  holds the memory near the filter's boundary (an error that stays); ``ignore`` carries
  none and winds up where two robots hold each other off trial after trial; a share of
  it does neither. A limit's clipping takes the full anti-windup: a memory learned as if
  unclipped (or a share) winds up outside the limits, where the clipped commands jitter
  on the acceleration bound trial after trial (docs/safety.md measured both on the
  generated families).

With ``damped``, a robot learns the stretch of a trial around the commands its filter
changed through a Q-filter (``smooth_learning``): there the step its memory takes (the
learned memory less the old one) is smoothed along the trial by a binomial kernel of
standard deviation Q_SIGMA seconds, blended out within three deviations. The filter's trims
switch on and off from sample to sample; the paper's law carries that roughness into the
memory and, on the generated families, either unlearns it slowly or lets it grow into a
heading oscillation (a period of about 2 s) that keeps the filter busy. Where the filter
did not act, and in every trial it left alone, the law is the paper's unchanged.

With ``robust`` every sample's step is smoothed, wherever the filter acted or not: the
robust ILC of noisy measurements (a Q-filter on the learning update). The paper's law
learns each trial's pose noise into its memory (eq. 9 steps by the gain times the
measured error); over the trials the memory grows rougher than the base can follow, the
filter's acceleration limits clip it more every trial, and the error grows back. The
kernel keeps the slow part of the step, which the tracking needs, and drops the sample-
to-sample roughness, which is noise: on the generated families with the paper's noise
the filter's changes fell from 29-62 a trial (first 10 trials) rising to 94-185 (last
10) to 4-30 falling to 4-16, and the error at trial 60 from 0.13-0.18 m to 0.11-0.13 m
(docs/safety.md, "Noise, and the limits"). It is the default on two wheels when the
scenario's poses are noisy (``config.safety.default_learning``).

docs/safety.md has the measurements behind the default (``config.safety.default_learning``):
``damped`` for two-wheel bodies, where it learned the paper's triangle and the generated
families best; ``split`` for skid-steer bases (Husky, Jackal), whose acceleration limits
let a barrier change a command by metres a second within a sample.

Units: metres, seconds, radians. Robots' poses (x, y, theta) are their tracked points.

The batch simulator, the robot node and the physics study each run ``learn_base`` before the
law's learning step and ``after_learning`` after it, once a trial (the filter itself:
``core.safety``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.safety import CHANGED, CHANGED_BARRIER, CHANGED_LIMITS, LEARNING

__all__ = ["LEARNING", "APPLIED", "FREEZE", "IGNORE", "SPLIT", "DAMPED", "ROBUST", "DAMPING",
           "Q_SIGMA",
           "learning_code", "learn_base", "freeze_flagged", "smooth_learning",
           "after_learning"]

APPLIED, FREEZE, IGNORE, SPLIT, DAMPED, ROBUST = 0, 1, 2, 3, 4, 5
#: ``damped``: the share of a barrier's change the memory takes in (a limit's, in full)
DAMPING = 0.05
#: ``damped``: the Q-filter's standard deviation [s] (``smooth_learning``; 0: none)
Q_SIGMA = 1.2


def learning_code(mode: str) -> int:
    if mode not in LEARNING:
        raise ValueError(f"safety learning must be one of {', '.join(LEARNING)}, got {mode!r}")
    return LEARNING.index(mode)


@njit(cache=True)
def learn_base(mode: int, memory: NDArray[np.float64], nominal: NDArray[np.float64],
               applied: NDArray[np.float64], flags: NDArray[np.int64],
               out: NDArray[np.float64]) -> None:
    """The memory the learning step starts from, written into ``out`` (R, T, 2).

    memory, nominal, applied : shape (R, T, 2): the trial's memory, the learned commands
    and the commands the filter let through; flags : shape (R, T). ``applied`` (APPLIED):
    memory + (applied - nominal); ``damped`` and ``robust``: the same where only a limit clipped the
    command (the anti-windup of learning with input saturation), memory + DAMPING
    (applied - nominal) where a barrier moved it; ``split``: the same where only a limit
    clipped it, the memory itself where a barrier moved it; ``freeze`` and ``ignore``: the
    memory itself (freeze and split then restore the old memory at changed samples after
    the step, ``freeze_flagged``).
    """
    for r in range(memory.shape[0]):
        for t in range(memory.shape[1]):
            for c in range(2):
                x = memory[r, t, c]
                f = flags[r, t] & CHANGED
                damped = mode == DAMPED or mode == ROBUST
                if f != 0 and (mode == APPLIED or (f == CHANGED_LIMITS
                                                   and (mode == SPLIT or damped))):
                    x += applied[r, t, c] - nominal[r, t, c]
                elif f != 0 and damped:
                    x += DAMPING * (applied[r, t, c] - nominal[r, t, c])
                out[r, t, c] = x


@njit(cache=True)
def freeze_flagged(mode: int, memory: NDArray[np.float64], flags: NDArray[np.int64],
                   learned: NDArray[np.float64]) -> None:
    """``freeze``: the learned memory keeps the old one at every changed sample; ``split``:
    at every sample where a barrier acted."""
    if mode != FREEZE and mode != SPLIT:
        return
    for r in range(memory.shape[0]):
        for t in range(memory.shape[1]):
            f = flags[r, t]
            if (mode == FREEZE and f & CHANGED) or (mode == SPLIT and f & CHANGED_BARRIER):
                learned[r, t, 0] = memory[r, t, 0]
                learned[r, t, 1] = memory[r, t, 1]


@njit(cache=True)
def smooth_learning(mode: int, dt: float, memory: NDArray[np.float64],
                    flags: NDArray[np.int64], learned: NDArray[np.float64]) -> None:
    """``damped``'s Q-filter, in place on ``learned`` (R, T, 2): around each command the
    filter changed (a ``CHANGED`` flag in ``flags`` (R, T)), the robot's step
    ``learned - memory`` is smoothed along the trial by a binomial kernel of standard
    deviation Q_SIGMA [s] at sample time ``dt`` (its order the nearest even one to
    4 (Q_SIGMA / dt)^2, cut at three standard deviations and weighed again at the trial's
    ends). A sample takes the smoothed step by the kernel's weight (1 at its centre) from
    the nearest changed command, and the paper's step beyond three deviations of every
    one: where the filter did not act the law is the paper's. ``robust``: every sample
    takes the smoothed step, in every trial. The weights are built by multiplications and
    divisions only: the same bits compiled and interpreted.
    """
    if (mode != DAMPED and mode != ROBUST) or Q_SIGMA <= 0.0:
        return
    s = Q_SIGMA / dt
    mid = max(1, int(2.0 * s * s + 0.5))  # half the kernel's order
    half = min(mid, int(3.0 * s) + 1)
    w = np.empty(2 * half + 1)
    w[half] = 1.0
    for j in range(1, half + 1):  # C(2 mid, mid + j) / C(2 mid, mid)
        w[half + j] = w[half + j - 1] * (mid - j + 1) / (mid + j)
        w[half - j] = w[half + j]
    n_t = memory.shape[1]
    step = np.empty(n_t)
    mix = np.empty(n_t)
    for r in range(memory.shape[0]):
        # how much of the smoothed step each sample takes: the kernel's own weight (1 at
        # its centre) from the nearest changed command, 0 beyond three deviations
        changed = mode == ROBUST
        for t in range(n_t):
            mix[t] = 1.0 if changed else 0.0
        for f in range(n_t if not changed else 0):
            if flags[r, f] & CHANGED:
                changed = True
                for j in range(max(-half, -f), min(half, n_t - 1 - f) + 1):
                    if w[half + j] > mix[f + j]:
                        mix[f + j] = w[half + j]
        if not changed:
            continue
        for c in range(2):
            for t in range(n_t):
                step[t] = learned[r, t, c] - memory[r, t, c]
            for t in range(n_t):
                if mix[t] == 0.0:
                    continue  # the paper's step, bit for bit
                acc = 0.0
                total = 0.0
                for j in range(max(-half, -t), min(half, n_t - 1 - t) + 1):
                    acc += w[half + j] * step[t + j]
                    total += w[half + j]
                learned[r, t, c] = memory[r, t, c] + step[t] + mix[t] * (acc / total - step[t])


@njit(cache=True)
def after_learning(mode: int, dt: float, memory: NDArray[np.float64],
                   flags: NDArray[np.int64], learned: NDArray[np.float64]) -> None:
    """What a learning reading does to the learned memory ``learned`` (R, T, 2) after the
    law's step from ``learn_base``: ``freeze_flagged``, then ``damped``'s Q-filter
    (``smooth_learning``). The batch simulator, the robot node and the physics study each
    call this once per trial."""
    freeze_flagged(mode, memory, flags, learned)
    smooth_learning(mode, dt, memory, flags, learned)
