"""What a plant node with bodies does with its contact events (the physics plant, the
physics bases): say each at once, in its log and its diagnostics (the launcher's console
says it), then act on the first one of a trial or a return (``protocol.physics_plant.
ContactWatch``): ask the leader to abort the trial the robots touched in, or end the run
with status 6."""

from __future__ import annotations

import time
from typing import Any

import msgs_schema as ms
from formation_ilc.nodes.common import fail
from formation_ilc.protocol.physics_plant import ContactEvent, ContactWatch, contact_then
from formation_ilc.system.exits import CONTACT

__all__ = ["ContactActing"]

#: how long a node that ends the run on a contact waits for its report to be taken [s]
ACKED_WITHIN_S = 2.0


class ContactActing:
    """A mixin for a ``ConfiguredNode`` with a ``diag_pub`` and a ``ready_pub``."""

    #: when it last asked for a held trial's abort (monotonic) [s]
    _asked: float = 0.0

    def before_contact_end(self) -> None:
        """Called before a contact ends the run (a node's last counts go out here)."""

    def act_on_contact(self, ev: ContactEvent, watch: ContactWatch,
                       *stamp: Any) -> bool:
        """Say ``ev`` (its diagnostics stamped ``*stamp``: ``ms.diagnostics_to_msg``'s
        stamp and trial grid), then act on it. Returns whether the run goes on."""
        node: Any = self
        dt = node.cfg.scenario.dt
        then = contact_then(ev, watch.reruns.get(ev.trial, 0), watch.retries)
        line = ev.line(dt, watch.tilt_limit)
        node.get_logger().warning(f"contact: {line}: {then}")
        node.diag_pub.publish(ms.diagnostics_to_msg(
            {"node": node.get_name(), "trial": ev.trial,
             "contact": ev.to_json(dt, watch.tilt_limit)}, *stamp))
        if not ev.acts:
            return True
        if ev.action == "stop":
            self.ask_abort(ev, watch)
        elif ev.action in ("abort", "give_up"):
            self.before_contact_end()
            # the report is the run's record of the contact that ends it (summary.json,
            # metrics.csv): the launcher must hold it before this process is gone; a
            # loaded machine took the exit first (the report was lost, the status kept)
            node.diag_pub.wait_for_all_acked(ACKED_WITHIN_S)
            fail(node, f"contact: {line}; {then} (--on-contact, docs/safety.md)", CONTACT)
            return False
        return True

    def ask_abort(self, ev: ContactEvent, watch: ContactWatch) -> None:
        """Ask the leader to abort the trial the robots touched in (its ready says why)."""
        node: Any = self
        self._asked = time.monotonic()
        line = ev.line(node.cfg.scenario.dt, watch.tilt_limit)
        node.ready_pub.publish(node.ready_msg(ev.trial, abort_slot=ev.slot,
                                              why=f"contact: {line}"))
