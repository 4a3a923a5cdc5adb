"""A hostile peer in a process of its own: it joins a running formation's domain, reads the
run id from the latched ``config`` and forges schedule events with it, as a stale or second
leader (or a buggy node) on the same domain and namespace would.

* ``--burst-at K``: the moment the ``end`` of iteration K goes by (its metrics row is about
  to be made, the next start not yet sent), a burst of ``--burst`` events (72 by default):
  starts of the next slots with the next and the same iterations, aborts of the slot that
  ended and of the next, ends and a ``done``, with every ``seq`` the leader could use next.
* ``--abort-committed K``: once every robot has said ready for iteration K+1 after the start
  of the slot that ran K (the leader commits it), an ``abort`` of that slot with the next
  ``seq``: the one the leader gives its next start, so a follower takes one or the other.
* ``--pose-flood K``: from the start of iteration K, for ``--flood-seconds`` (5), every
  robot's ``pose`` and ``shared_pose`` topics flooded as fast as this process can publish
  with replays of what they carried: every message of the earliest trial it heard (stale)
  and each topic's newest (a duplicate), as a stale bag replay or a node stuck in a loop
  would send them.

* ``--ready-as K``: once robot_1 said ready for iteration K, a copy of that ready in
  robot_1's name with another seed in its configuration (before, the leader stopped the
  run with status 2, blaming robot_1). With ``--impostor NAME``, the same copy also from a
  second node of this process named NAME in the formation's namespace (``robot_1``: the
  graph names its writer as robot_1's; before, the leader took it and stopped). The node
  is made once the first trial started, and stays until the run ends: its message is
  judged as the readers' graph names its writer, which a participant that left is not.
* ``--bad-report K``: at the start of iteration K, diagnostics in the plant's name whose
  contact slot is text (before, the launcher's monitor raised and the launcher ended with
  a traceback), and one whose contact line carries terminal escapes.

* ``--team-poses K``: from the start of iteration K, for every ``team/poses`` the plant
  sends, a copy for the next sample (its stamps one sample on) with every robot 1 km away,
  sent before the plant's own (before, the robots' safety filters took them: filter off).
* ``--truth K``: from the start of iteration K, for every true pose a simulated base sends
  on its ``truth`` (every topic named so in the graph), a copy 1 km away (before, the
  bridges took them: the true error read 63.9 m, exit 0).

It prints one JSON line per forgery on stdout (``{"forged": ..., "count": ...}``), and
exits once it has forged what it was asked to, or when the formation's configuration
writer is gone. Run in an enclave of the formation (``--secure``), a writer or reader its
permissions do not grant is refused at creation: it prints ``{"refused": TOPIC, "error":
...}`` and drops the forgeries that needed it (a ready in robot_1's name is then made up
from the trial events, as a robot's enclave reads no readies).

    python tests/stack/forger.py --burst-at 1 --abort-committed 3 [--pose-flood 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig


def burst_events(end: dict, run: str, start_seq: int, count: int) -> list[dict]:
    """``count`` forged events around the slot ``end`` names (its start had ``start_seq``):
    every combination a confused leader could send next, cycled."""
    q, i = int(end["slot"]), int(end["trial"])
    kinds: list[dict] = []
    for d in range(1, 5):  # every seq the leader may give its next events
        seq = start_seq + d
        # well formed (trial <= slot): only the seal can tell them from the leader's
        for slot, trial in ((q + 1, i + 1), (q + 1, i), (q + 2, i + 1), (q + 2, i + 2),
                            (q + 3, i + 1)):
            kinds.append({"event": "start", "trial": trial, "slot": slot, "seq": seq,
                          "stamp_ns": 0})
        kinds.append({"event": "abort", "trial": i, "slot": q, "seq": seq, "why": "forged"})
        kinds.append({"event": "abort", "trial": i + 1, "slot": q + 1, "seq": seq,
                      "why": "forged"})
        kinds.append({"event": "end", "trial": i + 1, "slot": q + 1, "seq": seq})
    kinds.append({"event": "done", "trial": i + 1, "slot": q + 1, "seq": start_seq + 5})
    out = []
    while len(out) < count:
        for k in kinds:
            if len(out) == count:
                break
            out.append({**k, "run": run, "forged": True})
    return out


#: messages of each pose topic the flood replays (with the topic's newest)
REPLAYED = 200


def _flood(heard: dict[str, list[bytes]], pubs: dict, seconds: float, alive) -> int:
    """Publish, for ``seconds`` or until ``alive()`` is False, replays of ``heard`` on
    their topics (``pubs``: topic -> publisher): each topic's first messages (stale by now)
    and its newest (a duplicate of what the robots just took), round after round. Returns
    the count published."""
    rounds = [(pubs[t], m) for t, msgs in heard.items() for m in msgs]
    count = 0
    end = time.monotonic() + seconds
    while rounds and time.monotonic() < end and alive():
        for p, m in rounds:
            p.publish(m)
        count += len(rounds)
    return count


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--namespace", default=ms.NAMESPACE)
    p.add_argument("--burst-at", type=int, default=None, metavar="K")
    p.add_argument("--burst", type=int, default=72, metavar="N")
    p.add_argument("--abort-committed", type=int, default=None, metavar="K")
    p.add_argument("--pose-flood", type=int, default=None, metavar="K")
    p.add_argument("--flood-seconds", type=float, default=5.0, metavar="S")
    p.add_argument("--ready-as", type=int, default=None, metavar="K")
    p.add_argument("--team-poses", type=int, default=None, metavar="K")
    p.add_argument("--bad-report", type=int, default=None, metavar="K")
    p.add_argument("--truth", type=int, default=None, metavar="K")
    p.add_argument("--impostor", default=None, metavar="NAME")
    p.add_argument("--timeout", type=float, default=900.0)
    a = p.parse_args()
    rclpy.init()
    # no services: an enclave grants a node's services to its own node only
    node = rclpy.create_node("forger", namespace="/forger", start_parameter_services=False,
                             parameter_overrides=[Parameter("start_type_description_service",
                                                            value=False)])
    topic = lambda t: ms.absolute(t, a.namespace)  # noqa: E731
    st: dict = {"run": "", "n": 0, "start": None, "readies": {}, "config_seen": False}

    def on_config(msg: String) -> None:
        d = json.loads(msg.data)
        st["run"] = d.get("run_id", "")
        st["n"] = RunConfig.from_json(d).scenario.n
        st["config_seen"] = True

    def on_event(msg: String) -> None:
        d = json.loads(msg.data)
        if d.get("run") != st["run"] or d.get("forged"):
            return
        if d.get("event") == "start":
            st["start"] = d
            st["readies"] = {}
        elif d.get("event") == "end":
            st["end"] = d

    def on_ready(msg: String) -> None:
        d = json.loads(msg.data)
        if d.get("run") == st["run"] and str(d.get("node", "")).startswith("robot_"):
            st["readies"][d["node"]] = d
            st.setdefault("last_ready", {})[d["node"]] = d

    def granted(make, *args):
        """A reader or writer, or None where the enclave's permissions refuse it."""
        try:
            return make(*args)
        except Exception as exc:  # noqa: BLE001 - refused at creation: a result
            print(json.dumps({"refused": args[1], "error": str(exc)[:200]}), flush=True)
            return None

    node.create_subscription(String, topic(ms.CONFIG), on_config, ms.LATCHED_QOS)
    node.create_subscription(String, topic(ms.TRIAL_EVENTS), on_event, ms.SAMPLE_QOS)
    reads_readies = granted(node.create_subscription, String, topic(ms.READY), on_ready,
                            ms.LATCHED_READER_QOS) is not None
    pub = granted(node.create_publisher, String, topic(ms.TRIAL_EVENTS), ms.SAMPLE_QOS)
    ready_pub = granted(node.create_publisher, String, topic(ms.READY), ms.LATCHED_QOS)
    #: the node named after a member (``--impostor``), made once a trial started: a member's
    #: name in the graph before the launch makes the launcher refuse to start (a second
    #: formation)
    impostor = None
    impostor_pub = None
    diag_pub = granted(node.create_publisher, DiagnosticArray, topic(ms.DIAGNOSTICS),
                       ms.LATCHED_QOS)
    config_sub = node.get_publishers_info_by_topic
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    todo = {k for k, v in (("burst", a.burst_at), ("abort", a.abort_committed),
                           ("flood", a.pose_flood), ("ready", a.ready_as),
                           ("report", a.bad_report), ("team", a.team_poses),
                           ("truth", a.truth))
            if v is not None}
    for needs, w in ((("burst", "abort"), pub), (("ready",), ready_pub),
                     (("report",), diag_pub)):
        if w is None:
            todo.difference_update(needs)
    if a.impostor and "ready" in todo:
        todo.add("impostor")  # until the run ends
    team: dict = {"last": None, "count": 0, "pub": None}

    def on_team(msg: Path) -> None:
        """A copy of the plant's team poses one sample on, every robot 1 km away."""
        start = st["start"]
        if start is None or start["trial"] < a.team_poses:
            return
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        last, team["last"] = team["last"], stamp
        if last is None or stamp <= last:
            return
        step = stamp - last
        out = Path()
        out.header = msg.header
        for p in msg.poses:
            q = PoseStamped()
            q.header.frame_id = p.header.frame_id
            ns = p.header.stamp.sec * 10**9 + p.header.stamp.nanosec + step
            q.header.stamp.sec, q.header.stamp.nanosec = divmod(ns, 10**9)
            q.pose = p.pose
            q.pose.position.x += 1000.0
            out.poses.append(q)
        ns = stamp + step
        out.header.stamp.sec, out.header.stamp.nanosec = divmod(ns, 10**9)
        team["pub"].publish(out)
        team["count"] += 1

    if a.team_poses is not None:
        team["pub"] = granted(node.create_publisher, Path, topic(ms.TEAM_POSES),
                              ms.SAMPLE_QOS)
        if team["pub"] is None:
            todo.discard("team")
        else:
            node.create_subscription(Path, topic(ms.TEAM_POSES), on_team, ms.SAMPLE_QOS)
    truth: dict = {"pubs": {}, "count": 0, "tried": set()}

    def on_truth(msg: PoseStamped, t: str) -> None:
        """A copy of a base's true pose, 1 km away."""
        start = st["start"]
        if start is None or start["trial"] < a.truth:
            return
        msg.pose.position.x += 1000.0
        truth["pubs"][t].publish(msg)
        truth["count"] += 1

    #: pose topic -> its first REPLAYED messages (stale by the flood) and its newest
    heard: dict[str, list[bytes]] = {}
    flood: dict[str, object] = {}  # pose topic -> publisher

    def hear(t: str, m: bytes) -> None:
        got = heard.setdefault(t, [])
        if len(got) <= REPLAYED:
            got.append(m)
        else:
            got[-1] = m  # the newest after the first REPLAYED

    deadline = time.monotonic() + a.timeout
    over = False
    try:
        while todo and time.monotonic() < deadline:
            try:
                ex.spin_once(timeout_sec=0.01)
            except KeyboardInterrupt:  # the test says the run is over (``end_forger``)
                over = True
                break
            if st["config_seen"] and not config_sub(topic(ms.CONFIG)):
                over = True
                break  # the leader is gone: the run is over
            start, end = st["start"], st.get("end")
            if a.impostor and impostor is None and start is not None:
                # once the first trial started (the launcher's check for a second
                # formation is behind), so that the readers have matched its writer
                # before it forges
                impostor = rclpy.create_node(
                    a.impostor, namespace=a.namespace, start_parameter_services=False,
                    parameter_overrides=[Parameter("start_type_description_service",
                                                   value=False)])
                impostor_pub = granted(impostor.create_publisher, String, topic(ms.READY),
                                       ms.LATCHED_QOS)
            if "truth" in todo and st["n"] and len(truth["tried"]) < st["n"]:
                # the bases' truth topics, as the graph lists them (under the bases'
                # driver namespaces): each read, and written 1 km away, where granted
                for t, _ in node.get_topic_names_and_types():
                    if t.endswith("/" + ms.BASE_TRUTH) and t not in truth["tried"]:
                        truth["tried"].add(t)
                        w = granted(node.create_publisher, PoseStamped, t, ms.ODOM_QOS)
                        if w is not None and granted(
                                node.create_subscription, PoseStamped, t,
                                lambda m, t=t: on_truth(m, t), ms.ODOM_QOS) is not None:
                            truth["pubs"][t] = w
                if len(truth["tried"]) >= st["n"] and not truth["pubs"]:
                    todo.discard("truth")  # every one refused by the permissions
            if "flood" in todo and st["n"] and not flood:  # the team's size is known
                for i in range(1, st["n"] + 1):
                    for t in (topic(ms.pose_topic(i)), topic(ms.shared_pose_topic(i))):
                        node.create_subscription(PoseStamped, t,
                                                 lambda m, t=t: hear(t, m), ms.SAMPLE_QOS,
                                                 raw=True)
                        flood[t] = node.create_publisher(PoseStamped, t, ms.SAMPLE_QOS)
            if "burst" in todo and start is not None and end is not None \
                    and end["trial"] == a.burst_at and end["slot"] == start["slot"]:
                evs = burst_events(end, st["run"], start["seq"], a.burst)
                for d in evs:
                    pub.publish(String(data=json.dumps(d)))
                todo.discard("burst")
                print(json.dumps({"forged": "burst", "count": len(evs), "after": end}),
                      flush=True)
            if "abort" in todo and start is not None \
                    and start["trial"] == a.abort_committed \
                    and len(st["readies"]) >= st["n"] > 0 \
                    and all(r["trial"] >= start["trial"] + 1 and r["seen"] >= start["seq"]
                            for r in st["readies"].values()):
                d = {"event": "abort", "trial": start["trial"], "slot": start["slot"],
                     "seq": start["seq"] + 1, "why": "forged", "run": st["run"],
                     "forged": True}
                pub.publish(String(data=json.dumps(d)))
                todo.discard("abort")
                print(json.dumps({"forged": "abort", "count": 1, "event": d}), flush=True)
            mine = st.get("last_ready", {}).get("robot_1")
            if not reads_readies and start is not None:  # made up from the events
                mine = {"node": "robot_1", "trial": int(start["trial"]) + 1,
                        "seen": int(start["seq"]), "run": st["run"], "config": {}}
            if "ready" in todo and mine is not None and mine.get("trial", -1) >= a.ready_as:
                cfg = dict(mine.get("config") or {})
                d = {**mine, "config": {**cfg, "seed": 999}}
                ready_pub.publish(String(data=json.dumps(d)))
                todo.discard("ready")
                print(json.dumps({"forged": "ready", "count": 1, "ready": d}), flush=True)
                if impostor_pub is not None:
                    impostor_pub.publish(String(data=json.dumps(d)))
                    print(json.dumps({"forged": "ready_as_node", "count": 1,
                                      "node": impostor.get_fully_qualified_name()}),
                          flush=True)
            if "report" in todo and start is not None and start["trial"] >= a.bad_report:
                plant = ms.SIM_NODE
                k = int(start["trial"])
                line = "\x1b[2K\rtrial 99/99 ... every trial is in\x1b[1A"
                for contact in ({"slot": "boom", "line": "x", "action": "stop"},
                                {"slot": int(start["slot"]), "sample": 1, "line": line,
                                 "action": "continue", "pairs": [[1, 2]]}):
                    diag_pub.publish(ms.diagnostics_to_msg(
                        {"node": plant, "trial": k, "contact": contact}, 0))
                diag_pub.publish(ms.diagnostics_to_msg(
                    {"node": plant, "trial": k, "contact_report": {"slot": 0,
                                                                   "pairs": [[1, 2]] * 7}}, 0))
                todo.discard("report")
                print(json.dumps({"forged": "report", "count": 3}), flush=True)
            if "flood" in todo and start is not None and start["trial"] >= a.pose_flood:
                count = _flood(heard, flood, a.flood_seconds,
                               lambda: bool(config_sub(topic(ms.CONFIG))))
                todo.discard("flood")
                print(json.dumps({"forged": "pose_flood", "count": count,
                                  "topics": len(heard)}), flush=True)
        # a reliable writer that exits at once may not have delivered: wait until every
        # reader acknowledged the forgeries (bounded; a reader that left is no longer waited
        # for). Not once the run is over: a reader killed at its end is waited for until
        # its lease runs out, and there is no one left to forge for
        for w in (pub, ready_pub, diag_pub, impostor_pub):
            if w is not None and not over:
                w.wait_for_all_acked(Duration(seconds=10))
        if impostor_pub is not None and "ready" not in todo:  # it stayed until the end
            todo.discard("impostor")
        if team["count"]:  # it went on until the run ended
            print(json.dumps({"forged": "team_poses", "count": team["count"]}), flush=True)
            todo.discard("team")
        if truth["count"]:  # it went on until the run ended
            print(json.dumps({"forged": "truth", "count": truth["count"],
                              "topics": sorted(truth["pubs"])}), flush=True)
            todo.discard("truth")
    finally:
        if impostor is not None:
            impostor.destroy_node()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if not todo else 1


if __name__ == "__main__":
    sys.exit(main())
