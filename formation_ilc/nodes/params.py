"""ROS parameters the ROS way: descriptors, read-only, one-line refusals.

A node declares its table of ``formation_ilc.config.params.Param`` with ``declare``: each
parameter gets a descriptor (description with unit and range, an integer or floating-point
range, read-only), and its value, from ``-p`` or a ``--params-file`` YAML (node-keyed or
``/**``), is checked before it is declared: a wrong type, a value out of range or not among
the choices is a ``ParameterError`` naming the parameter in one line, which ``spin_main``
prints before it exits with status 2. Every parameter is read-only once declared
(``ros2 param set`` is refused with rclpy's reason), and ``use_sim_time`` true is refused
at start and at run time: the stack keeps its own time (see docs/ros-tools.md).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from formation_ilc.config.params import BIG, Param, choice_text, describe, unknown_key

__all__ = ["ParameterError", "declare", "effective", "probe_overrides", "SIM_TIME_REFUSED"]

SIM_TIME_REFUSED = ("use_sim_time is not supported: the stack keeps its own time (lockstep "
                    "labels on /clock are read as messages, wallclock is the system clock)")


class ParameterError(ValueError):
    """A parameter no run can have: one line naming it (status 2)."""


def _kind(default: Any) -> str:
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, float):
        return "a number"
    if isinstance(default, list):
        return ("a list of strings" if default and isinstance(default[0], str)
                else "a list of numbers")
    return "a string"


def _coerce(p: Param, value: Any) -> Any:
    """``value`` as the parameter's type (an integer where a number is expected is taken),
    or ParameterError."""
    d = p.default
    ok: bool
    if isinstance(d, bool):
        ok = isinstance(value, bool)
    elif isinstance(d, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(d, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if ok:
            value = float(value)
    elif isinstance(d, list):
        want = str if d and isinstance(d[0], str) else float
        items = list(value) if isinstance(value, (list, tuple)) else None
        ok = items is not None and all(
            isinstance(v, want) or (want is float and isinstance(v, int)
                                    and not isinstance(v, bool)) for v in items)
        if ok and items is not None:
            value = [want(v) for v in items]
    else:
        ok = isinstance(value, str)
    if not ok:
        raise ParameterError(f"parameter {p.name}: expected {_kind(d)}, got {value!r}"[:300])
    return value


def check(p: Param, value: Any) -> Any:
    """The value ``p`` takes for ``value``, or ParameterError: type, range, choices."""
    value = _coerce(p, value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        lo = p.lo if p.lo is not None else -math.inf
        hi = p.hi if p.hi is not None else math.inf
        if not (lo <= value <= hi):
            shown = "inf" if hi >= BIG else f"{hi:g}"
            raise ParameterError(f"parameter {p.name}: {value} is outside {lo:g} .. {shown} "
                                 f"({p.description})")
    why = p.check(value)
    if why is not None:
        raise ParameterError(f"parameter {p.name}: {why}")
    return value


def descriptor(p: Param) -> ParameterDescriptor:
    d = ParameterDescriptor(name=p.name, description=describe(p), read_only=True)
    if p.choices:
        d.additional_constraints = f"one of: {choice_text(p.choices)}"
    if isinstance(p.default, int) and not isinstance(p.default, bool):
        d.integer_range = [IntegerRange(from_value=int(p.lo if p.lo is not None else -BIG),
                                        to_value=int(p.hi if p.hi is not None else BIG))]
    elif isinstance(p.default, float) and (p.lo is not None or p.hi is not None):
        d.floating_point_range = [FloatingPointRange(
            from_value=float(p.lo if p.lo is not None else -1e300),
            to_value=float(p.hi if p.hi is not None else 1e300))]
    return d


def declare(node: Node, table: tuple[Param, ...] | list[Param], **given: Any) -> None:
    """Declare ``table`` on ``node`` (read-only, with descriptors); ``given`` values win over
    overrides (the container mode's robot_id). ParameterError for a bad value or a
    ``use_sim_time`` true."""
    if node.get_parameter("use_sim_time").value:
        raise ParameterError(f"parameter {SIM_TIME_REFUSED}")
    overrides = node._parameter_overrides  # -p and --params-file, as rcl matched them
    tables = getattr(node, "_formation_params", {})
    tables.update({p.name: p for p in table})
    node._formation_params = tables
    for key in sorted(overrides):  # a misspelt key would silently leave its default
        why = unknown_key(key, list(tables))
        if why is not None:
            raise ParameterError(why)
    for p in table:
        if p.name in given:
            value = check(p, given[p.name])
        elif p.name in overrides:
            value = check(p, overrides[p.name].value)
        else:
            value = p.default
        node.declare_parameter(p.name, value, descriptor(p), ignore_override=True)
    node.add_on_set_parameters_callback(_refuse_sim_time)


def effective(node: Node, values: dict[str, Any]) -> None:
    """Make the (read-only) parameters ``values`` read what the node runs with: the run
    configuration it took from the leader, a preset's topics and limits, the scenario's
    value where a parameter "keeps the scenario's". Their descriptions say so
    (``Param.effective``); a parameter event goes out as for any change."""
    table: dict[str, Param] = getattr(node, "_formation_params", {})
    params, descriptors = [], {}
    for name, value in values.items():
        p = table.get(name)
        if p is None or not node.has_parameter(name):
            continue
        v = _coerce(p, value)
        if v == node.get_parameter(name).value:
            continue
        params.append(Parameter(name, value=v))
        descriptors[name] = node.describe_parameter(name)
    if params:
        # rclpy's own path for a declaration (descriptors given: read-only is not checked)
        res = node._set_parameters_atomically_common(params, descriptors)
        if not res.successful:
            raise ParameterError(f"parameters {', '.join(descriptors)}: {res.reason}")


def _refuse_sim_time(params: list[Parameter]) -> SetParametersResult:
    for p in params:
        if p.name == "use_sim_time" and p.value:
            return SetParametersResult(successful=False, reason=SIM_TIME_REFUSED)
    return SetParametersResult(successful=True)


@contextlib.contextmanager
def probe_overrides(name: str, namespace: str, **kwargs: Any) -> Iterator[dict[str, Any]]:
    """The parameter values (``-p`` and ``--params-file``) a node named ``name`` in
    ``namespace`` would get, before that node exists: a node whose name follows a
    parameter (robot_id) needs it first. A short-lived node without services or rosout;
    remappings of the node's name and namespace apply to it as to the real one.

    A context manager: create the real node inside the ``with`` block. rmw destroys a
    context's DDS participant with its last node, so a probe destroyed before the real
    node existed made each robot process announce a participant that lived 0.2 s; every
    other participant discovered it too, and in a secure run began an authentication
    handshake with it that went on until its discovery lease ran out. So a keeper holds
    the participant instead (``KEEPER``: hidden, no remaps, no services): the probe itself
    is gone before the real node is made. The real node may have the probe's name (the
    fake driver's; a robot's under ``-r __node:=robot_I``), and rmw's graph files a node's
    publishers and subscriptions under the first node of that name in the participant:
    made beside the probe, they were dropped with it, and the graph showed the real node
    with none."""
    # nor its type description service: a secure run's permissions grant a node's
    # services under the node's own name only, and Enforce refused the probe's
    quiet: dict[str, Any] = dict(enable_rosout=False, start_parameter_services=False,
                                 parameter_overrides=[Parameter(_TYPE_DESCRIPTION,
                                                                value=False)])
    probe = Node(name, namespace=namespace, **quiet, **kwargs)
    try:
        found = {k: p.value for k, p in probe._parameter_overrides.items()
                 if k != _TYPE_DESCRIPTION}
        keeper = Node(KEEPER, namespace="/", use_global_arguments=False,
                      context=kwargs.get("context"), **quiet)
    finally:
        probe.destroy_node()
    try:
        yield found
    finally:
        keeper.destroy_node()


#: the node that holds a process's DDS participant while its real node is made
#: (``probe_overrides``); hidden (a leading underscore) from ``ros2 node list``
KEEPER = "_formation_ilc_keeper"


#: rclpy's parameter that switches a node's type description service on (default true)
_TYPE_DESCRIPTION = "start_type_description_service"
