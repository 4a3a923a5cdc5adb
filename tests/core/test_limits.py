"""Speed and acceleration limits: plan checks, the time scale that fits, run-time limiting."""

import math

import numpy as np
import pytest

from formation_ilc.config.bases import BASES, fit_limits
from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.limits import Limits, RateLimiter, check_inputs, scale_needed


def test_check_names_worst_excess():
    u = np.zeros((2, 5, 2))
    u[0, 2, 0] = 0.3      # 1.5 x v_max
    u[1, 3, 1] = 2.0      # 2 x omega_max, the worst
    lim = [Limits(0.2, 1.0), Limits(0.2, 1.0)]
    v = check_inputs(u, 0.5, lim)
    assert (v.robot, v.sample, v.quantity) == (2, 3, "turn rate")
    assert v.line(0.5) == ("robot 2: desired turn rate 2 rad/s at t = 1.5 s exceeds its limit "
                           "1 rad/s")
    assert check_inputs(u, 0.5, [Limits(0.3, 2.0)] * 2) is None  # equal is inside


def test_acceleration_from_rest():
    u = np.full((1, 3, 2), 0.1)
    assert check_inputs(u, 0.1, [Limits(a_max=0.5)]).quantity == "acceleration"
    assert check_inputs(u, 0.1, [Limits(a_max=1.0, alpha_max=1.0)]) is None
    assert scale_needed(u, 0.1, [Limits(a_max=0.5)]) == pytest.approx(2.0)


def test_limits_refuse_nonsense():
    with pytest.raises(ValueError, match="v_max must be > 0"):
        Limits(v_max=0.0)
    with pytest.raises(ValueError, match="a_max"):
        Limits(a_max=math.nan)


def test_triangle_too_fast_for_turtlebots_fits_when_stretched():
    sc = load_scenario("paper-triangle3").for_plant("arc")
    line = fit_limits(sc, [BASES["turtlebot3"].limits] * 3)
    assert line is not None and "\n" not in line
    assert line.startswith("robot 3: desired speed 0.505 m/s at t = 24.0 s exceeds its "
                           "limit 0.22 m/s; --time-scale ")
    scale = float(line.rsplit("--time-scale ", 1)[1].split()[0])
    slow = sc.with_options(time_scale=scale)
    assert slow.samples == round(140 * scale)
    assert fit_limits(slow, [BASES["turtlebot3"].limits] * 3) is None
    for name in ("jackal", "husky", "p3dx"):
        assert fit_limits(sc, [BASES[name].limits] * 3) is None


def test_rate_limiter_clips_and_counts():
    rl = RateLimiter(Limits(v_max=1.0, omega_max=1.0, a_max=1.0, alpha_max=2.0))
    assert rl.limit(0.5, 0.0, 0.0) == (0.5, 0.0, False)   # no previous command: speed only
    v, w, clipped = rl.limit(2.0, -2.0, 0.1)
    assert clipped and v == pytest.approx(0.6) and w == pytest.approx(-0.2)
    assert rl.counts() == {"commands": 2, "clipped_speed": 1, "clipped_accel": 1}
    rl.reset(1.0)
    assert rl.limit(0.05, 0.0, 1.1)[:2] == (0.05, 0.0)
