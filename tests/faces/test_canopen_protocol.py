"""hil.protocol.canopen: COB-ID classes and describe_frame (the recorder's decoder)."""

from __future__ import annotations

import random

from hil.protocol.canopen import abort_text, classify, describe_frame


def test_classify_cob_ids():
    # L16873-L16899
    assert classify(0x000) == ("nmt", None)
    assert classify(0x080) == ("sync", None)
    assert classify(0x081) == ("emcy", 1)
    assert classify(0x0FF) == ("emcy", 127)
    assert classify(0x185) == ("tpdo1", 5)
    assert classify(0x505) == ("rpdo4", 5)
    assert classify(0x58A) == ("sdo_tx", 10)
    assert classify(0x60A) == ("sdo_rx", 10)
    assert classify(0x705) == ("heartbeat", 5)


def test_describe_manual_sdo_example():
    # L16985-L16993: write P7.001 (2701h) = 300000
    d = describe_frame(0x605, bytes.fromhex("23012700E0930400"))
    assert d["kind"] == "sdo_rx" and d["command"] == "initiate download"
    assert (d["index"], d["sub"], d["value"]) == (0x2701, 0, 300_000)
    d = describe_frame(0x585, bytes.fromhex("6001270000000000"))
    assert d["command"] == "initiate download" and d["scs"] == 3


def test_describe_abort_emcy_nmt_heartbeat():
    d = describe_frame(0x585, bytes.fromhex("8000300000000206"))
    assert d["abort_code"] == 0x06020000
    assert d["abort_text"] == "Object does not exist in the object dictionary"
    d = describe_frame(0x85, bytes([0x05, 0x73, 0x01, 0x11, 0x00, 0, 0, 0]))
    assert (d["error_code"], d["error_register"], d["alarm"]) == (0x7305, 1, "AL011")
    assert describe_frame(0, bytes([0x82, 5]))["command"] == "reset communication"
    assert describe_frame(0x705, bytes([127]))["state"] == "PRE-OPERATIONAL"
    assert describe_frame(0x705, b"", remote=True)["kind"] == "node_guard_request"
    assert abort_text(0x12345678) == "unknown abort code"


def test_describe_never_raises():
    rng = random.Random(7)
    for _ in range(5000):
        cid = rng.randrange(0x800)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        d = describe_frame(cid, data)
        assert "kind" in d
