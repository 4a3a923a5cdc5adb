"""The launcher's lifecycle manager: it brings managed bridges (``lifecycle:=true``) up and
down through their standard ``change_state`` services, as a lab's lifecycle manager would.

``step()`` (called from the launcher's loop) asks each bridge to configure, and once that
succeeded to activate; a configure that fails (the bridge's driver is not there yet) is
asked again every ``RETRY`` s. ``deactivate()`` at the end asks every active bridge to
deactivate (it sends its driver a zero command) and waits for the answers a short while.
"""

from __future__ import annotations

import time
from typing import Any

__all__ = ["Transitions", "RETRY"]

#: [s] between two configure requests to a bridge whose driver was not there
RETRY = 1.0


class Transitions:
    """Drives the bridges ``names`` (full node names) from ``node`` (an rclpy node)."""

    def __init__(self, node: Any, names: list[str]):
        from lifecycle_msgs.srv import ChangeState

        self.node = node
        self.clients = {n: node.create_client(ChangeState, f"{n}/change_state") for n in names}
        #: per bridge: 'configure', 'activate' (the next request), 'active'
        self.phase = dict.fromkeys(names, "configure")
        self.pending: dict[str, Any] = {}
        self.due = dict.fromkeys(names, 0.0)
        self.failures = dict.fromkeys(names, 0)

    @property
    def active(self) -> bool:
        return all(p == "active" for p in self.phase.values())

    def _request(self, name: str, transition: int) -> None:
        from lifecycle_msgs.srv import ChangeState

        req = ChangeState.Request()
        req.transition.id = transition
        self.pending[name] = self.clients[name].call_async(req)

    def step(self) -> list[str]:
        """Move every bridge one step on; the lines to print."""
        from lifecycle_msgs.msg import Transition

        lines = []
        now = time.monotonic()
        for name, phase in self.phase.items():
            fut = self.pending.get(name)
            if fut is not None:
                if not fut.done():
                    continue
                del self.pending[name]
                ok = fut.result() is not None and fut.result().success
                if phase == "configure" and not ok:
                    self.failures[name] += 1
                    if self.failures[name] == 1:
                        lines.append(f"{name}: configure failed (its driver is not there yet; "
                                     f"its log says what is missing): asking again every "
                                     f"{RETRY:g} s")
                    self.due[name] = now + RETRY
                    continue
                if phase == "configure":
                    phase = self.phase[name] = "activate"
                elif phase == "activate":
                    if ok:
                        phase = self.phase[name] = "active"
                        lines.append(f"{name}: configured and active (lifecycle)")
                    continue
            if phase == "active" or now < self.due[name]:
                continue
            if not self.clients[name].service_is_ready():
                continue
            self._request(name, Transition.TRANSITION_CONFIGURE if phase == "configure"
                          else Transition.TRANSITION_ACTIVATE)
        return lines

    def deactivate(self, spin: Any, timeout: float = 2.0) -> list[str]:
        """Ask every active bridge to deactivate (its base stops), spinning ``spin(dt)``
        for the answers at most ``timeout`` s; the bridges that did not answer."""
        from lifecycle_msgs.msg import Transition

        asked = [n for n, p in self.phase.items() if p == "active"]
        for name in asked:
            self._request(name, Transition.TRANSITION_DEACTIVATE)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not all(self.pending[n].done() for n in asked):
            spin(0.05)
        return [n for n in asked if not (self.pending[n].done()
                                         and self.pending[n].result() is not None
                                         and self.pending[n].result().success)]
