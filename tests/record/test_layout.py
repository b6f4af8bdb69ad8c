"""The Foxglove layout fixture references panels and topics that exist."""

from __future__ import annotations

import json
from pathlib import Path

from hil.record import topics

LAYOUT = Path(__file__).resolve().parents[2] / "fixtures" / "foxglove" / "hil-drive-layout.json"


def _leaves(node):
    if isinstance(node, str):
        yield node
    else:
        yield from _leaves(node["first"])
        yield from _leaves(node["second"])


def test_layout_is_consistent_with_topic_names():
    doc = json.loads(LAYOUT.read_text())
    assert set(_leaves(doc["layout"])) == set(doc["configById"])
    known = {
        topics.drive_state("drive1"),
        topics.can_raw("can0"),
        topics.canopen_sdo("can0"),
        topics.LOG,
        topics.TIMING_VERDICTS,
    }
    known |= {
        topics.dio("drive1", line)
        for line in [
            "DI1",
            "DI2",
            "DI3",
            "DI4",
            "DO1",
            "DO2",
            "DO3",
            "DO4",
            "STO_A",
            "STO_B",
            "FDBK",
        ]
    }
    used = set()
    for panel_id, cfg in doc["configById"].items():
        for p in cfg.get("paths", []):
            used.add(p["value"].split(".")[0])
        for key in ("topicPath", "topicToRender"):
            if key in cfg:
                used.add(cfg[key])
        assert panel_id.split("!")[0] in {
            "Plot",
            "StateTransitions",
            "RawMessages",
            "RosOut",
            "Table",
        }
    assert used <= known, used - known
