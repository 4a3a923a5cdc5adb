"""Bounded message cost: a Path longer than a trial is refused from its length, before it
is deserialized (a 14 MB forged Path stalled every node for about 85 s while rclpy built its
Python objects); every real trajectory and link tick fits the bound."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
from nav_msgs.msg import Path  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

import msgs_schema as ms  # noqa: E402


def _bytes(poses: int, frame: str = ms.WORLD_FRAME) -> bytes:
    eta = np.zeros((poses, 3))
    return serialize_message(ms.trajectory_to_path(eta, range(poses), frame))


@pytest.mark.parametrize("poses", [0, 1, 141, 1001])
def test_every_real_path_fits_its_bound_even_with_the_longest_frame_id(poses):
    for frame in (ms.WORLD_FRAME, "f" * ms.FRAME_ID_MAX):
        data = _bytes(poses, frame)
        assert len(data) <= ms.path_limit(poses)
        msg = ms.path_from_raw(data, poses)
        assert len(msg.poses) == poses and msg.header.frame_id == frame


def test_a_path_longer_than_the_trial_is_refused_before_it_is_deserialized(monkeypatch):
    calls = []
    real = ms.deserialize
    monkeypatch.setattr(ms, "deserialize", lambda data, cls: calls.append(1) or real(data, cls))
    big = _bytes(300)  # twice a trial of 140 samples (a size bound: 141 exactly is checked after)
    with pytest.raises(ms.MalformedMessage, match=r"trajectory of \d+ bytes: longer than 141 "
                                                  r"poses can be"):
        ms.path_from_raw(big, 141, "trajectory")
    forged = b"\x00\x01\x00\x00" + b"\x00" * (14 << 20)  # 14 MB of anything
    with pytest.raises(ms.MalformedMessage, match="longer than 1 poses"):
        ms.path_from_raw(forged, 1, "link tick")
    assert calls == []  # neither reached the deserializer
    assert ms.path_from_raw(_bytes(141), 141) is not None and calls == [1]
    built = Path()
    assert ms.path_from_raw(built, 1) is built  # an in-process caller's message
