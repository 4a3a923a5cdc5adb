"""A small URDF of each robot base, for ``robot_i/robot_description``.

Viewers (RViz's RobotModel display, Foxglove's URDF layer) draw a robot from its URDF on
its ``base_link`` frame. Each base here is written from its maker's published dimensions
(no maker's or community model is copied): the body as a box (the TurtleBot 4 as a
cylinder), the two drive wheels as cylinders, all visuals of one link, ``base_link``, so
that the only frame a viewer needs is the one the stack publishes (``robot_i/base_link``
on /tf). ``base_link`` is on the ground below the middle of the drive axle, x forward, z
up (REP-103); the body's centre is ``body_x`` ahead of it.

Sources (outer dimensions length x width x height, drive wheel diameter, track):

* p3dx: Adept MobileRobots, Pioneer 3-DX datasheet: 455 x 381 x 237 mm, wheels 195 mm,
  track 330 mm (``model/robots/p3dx_size.urdf``, the physics plant's body, has the same);
* turtlebot3 (Burger): ROBOTIS e-Manual, specifications: 138 x 178 x 192 mm, wheels 66 mm,
  track 160 mm;
* turtlebot4 (standard, iRobot Create 3 base): TurtleBot 4 user manual, hardware
  specifications: 342 x 339 x 351 mm, Create 3 wheels 72 mm, track 235 mm;
* jackal: Clearpath Jackal UGV datasheet: 508 x 430 x 250 mm, wheels 196 mm (4, two drawn
  per side as one), track 375 mm;
* husky: Clearpath Husky A200 datasheet: 990 x 670 x 390 mm, wheels 330 mm (4), track
  555 mm.

Pure: text only; ``BODIES`` keys are the base presets' names (``config.bases``).
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

__all__ = ["Body", "BODIES", "robot_description", "body_of"]


@dataclass(frozen=True)
class Body:
    """A base's outer dimensions [m]: length, width, height; drive wheel diameter and
    track; the body's centre ahead of the axle (``body_x``); a cylinder body (TurtleBot
    4); four wheels (two per side, ``wheelbase`` apart) or two."""

    length: float
    width: float
    height: float
    wheel: float
    track: float
    body_x: float = 0.0
    round: bool = False
    wheelbase: float = 0.0
    source: str = ""


BODIES: dict[str, Body] = {
    "p3dx": Body(0.455, 0.381, 0.237, 0.195, 0.330, -0.045,
                 source="Adept MobileRobots, Pioneer 3-DX datasheet"),
    "turtlebot3": Body(0.138, 0.178, 0.192, 0.066, 0.160, -0.032,
                       source="ROBOTIS e-Manual, TurtleBot3 Burger specifications"),
    "turtlebot4": Body(0.342, 0.339, 0.351, 0.072, 0.235, 0.0, round=True,
                       source="TurtleBot 4 user manual, hardware specifications"),
    "jackal": Body(0.508, 0.430, 0.250, 0.196, 0.375, 0.0, wheelbase=0.262,
                   source="Clearpath Jackal UGV datasheet"),
    "husky": Body(0.990, 0.670, 0.390, 0.330, 0.555, 0.0, wheelbase=0.512,
                  source="Clearpath Husky A200 datasheet"),
}


def body_of(name: str) -> Body:
    """The body of base ``name`` (``husky-imu`` is a husky); ValueError for another."""
    key = "husky" if name == "husky-imu" else name
    try:
        return BODIES[key]
    except KeyError:
        raise ValueError(f"no body {name!r} (have: {', '.join(BODIES)})") from None


def _f(x: float) -> str:
    return f"{x:.4f}".rstrip("0").rstrip(".") or "0"


def robot_description(base: str, prefix: str) -> str:
    """The URDF of base ``base`` with its one link named ``{prefix}base_link``
    (``robot_1/`` gives ``robot_1/base_link``, the robot's frame on /tf)."""
    b = body_of(base)
    r = b.wheel / 2.0
    # the body sits on the wheels' axle height, up to the base's height
    body_h = max(b.height - r, 0.05)
    body_z = b.height - body_h / 2.0
    link = f"{prefix}base_link"
    if b.round:
        body = (f'<cylinder radius="{_f(max(b.length, b.width) / 2.0)}" '
                f'length="{_f(body_h)}"/>')
    else:
        body = f'<box size="{_f(b.length)} {_f(b.width)} {_f(body_h)}"/>'
    visuals = [f'    <visual name="body">\n      <origin xyz="{_f(b.body_x)} 0 {_f(body_z)}"/>\n'
               f'      <geometry>{body}</geometry>\n'
               f'      <material name="body"/>\n'
               f'    </visual>']
    xs = [0.0] if b.wheelbase <= 0 else [b.wheelbase / 2.0, -b.wheelbase / 2.0]
    for side, y in (("left", b.track / 2.0), ("right", -b.track / 2.0)):
        for k, x in enumerate(xs):
            visuals.append(
                f'    <visual name="{side}_wheel_{k}">\n'
                f'      <origin xyz="{_f(x)} {_f(y)} {_f(r)}" rpy="1.5708 0 0"/>\n'
                f'      <geometry><cylinder radius="{_f(r)}" length="{_f(min(0.05, r))}"/>'
                f'</geometry>\n'
                f'      <material name="wheel"/>\n'
                f'    </visual>')
    return (f'<?xml version="1.0"?>\n'
            f'<!-- {base}: written by formation-ilc from the maker\'s dimensions '
            f'({b.source}); not the maker\'s model -->\n'
            f'<robot name={quoteattr(f"{prefix}{base}")}>\n'
            f'  <material name="body"><color rgba="0.8 0.1 0.1 1"/></material>\n'
            f'  <material name="wheel"><color rgba="0.1 0.1 0.1 1"/></material>\n'
            f'  <link name={quoteattr(link)}>\n' + "\n".join(visuals) + "\n  </link>\n</robot>\n")
