"""The shipped Foxglove layout (docs/foxglove/formation-ilc.layout.json) shows only topics
the stack publishes under the names msgs_schema gives them (a renamed topic fails here),
with the 3D view, error-vs-time and error-vs-trial plots and the diagnostics."""

from __future__ import annotations

import json
from pathlib import Path

import msgs_schema as ms

LAYOUT = Path(__file__).resolve().parents[2] / "docs" / "foxglove" / "formation-ilc.layout.json"


def _panels(tree) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _panels(tree["first"]) + _panels(tree["second"])


def test_layout_names_only_published_topics_and_has_every_panel():
    d = json.loads(LAYOUT.read_text())
    cfg = d["configById"]
    assert sorted(_panels(d["layout"])) == sorted(cfg)
    kinds = {p.split("!")[0] for p in cfg}
    assert {"3D", "Plot", "DiagnosticSummary"} <= kinds
    known = {ms.absolute(t) for t, _, _ in ms.topic_table(6) + ms.view_topic_table(6)}
    used: set[str] = set()
    for pid, c in cfg.items():
        if pid.startswith("3D!"):
            used |= set(c["topics"])
        elif pid.startswith("Plot!"):
            paths = [p["value"] for p in c["paths"]]
            if c.get("xAxisVal") == "custom":
                paths.append(c["xAxisPath"]["value"])
            used |= {p.split(".")[0] for p in paths}
        elif "topicToRender" in c:
            used.add(c["topicToRender"])
        elif "topicPath" in c:
            used.add(c["topicPath"])
    assert used and used <= known, used - known
    for kind in ("pose", "desired_pose", "desired_path"):
        assert ms.absolute(f"robot_1/{kind}") in used
    assert ms.absolute(ms.MARKERS) in used
    assert ms.absolute(ms.trial_error_topic(1)) in used
    assert ms.absolute(ms.tracking_error_topic(6)) in used
