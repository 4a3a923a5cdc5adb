"""Each base's URDF (``config.urdf``): a robot a URDF parser loads (PyBullet's, the physics
extra's), one link named for the robot's frame, the size the base's preset keeps clear."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from formation_ilc.config.bases import BASES
from formation_ilc.config.urdf import BODIES, body_of, robot_description


def load_urdf(text: str, tmp_path) -> tuple[str, int]:
    """(base link name, number of visual shapes) of ``text`` as PyBullet loads it."""
    pb = pytest.importorskip("pybullet")  # the physics extra; CI installs it
    f = tmp_path / "robot.urdf"
    f.write_text(text)
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(f), physicsClientId=client)
        base, _ = pb.getBodyInfo(body, physicsClientId=client)
        shapes = pb.getVisualShapeData(body, physicsClientId=client)
        return base.decode(), len(shapes)
    finally:
        pb.disconnect(client)


@pytest.mark.parametrize("base", sorted(BODIES))
def test_every_base_is_a_urdf_of_one_link_on_the_robots_frame(base, tmp_path):
    text = robot_description(base, "robot_2/")
    root = ET.fromstring(text.encode())
    assert root.tag == "robot"
    assert [link.get("name") for link in root.iter("link")] == ["robot_2/base_link"]
    name, shapes = load_urdf(text, tmp_path)
    assert name == "robot_2/base_link"
    b = body_of(base)
    assert shapes == 1 + (4 if b.wheelbase > 0 else 2)  # the body and its drive wheels
    # the outer size the safety filter and the clearance check use
    assert (b.length, b.width) == BASES[base].size, base


def test_an_unknown_body_is_refused_naming_the_known():
    with pytest.raises(ValueError, match="have: p3dx"):
        robot_description("roomba", "robot_1/")
    assert body_of("husky-imu") == BODIES["husky"]
