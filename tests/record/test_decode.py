"""Decoded channels: SDO and Modbus pairing, and decoding that never crashes the recorder."""

from __future__ import annotations

import random

import pytest
from rec_helpers import frame

from hil.record import recorder as recorder_mod
from hil.record import topics
from hil.record.modbus_pairing import ModbusPairing, crc16, pdu_of
from hil.record.reader import Recording
from hil.record.recorder import Recorder
from hil.record.sdo_pairing import SdoPairing

T0 = 1_700_000_000_000_000_000


def test_sdo_write_from_the_manual():
    # P7.001 (2701h) = 300,000 on node 10: request 23 01 27 00 E0 93 04 00, reply 60h
    # (manual L16979-L16993)
    p = SdoPairing()
    assert p.feed(0x60A, bytes.fromhex("23012700E0930400"), 100) == []
    (txn,) = p.feed(0x58A, bytes.fromhex("6001270000000000"), 1_100)
    assert txn["object"] == "2701h:00" and txn["value"] == 300_000 and txn["size"] == 4
    assert txn["status"] == "ok" and txn["latency_ns"] == 1_000 and txn["frames"] == 2



def test_a_signed_cia402_object_reads_signed_in_the_sdo_record_and_the_frame():
    """607Ah target position (INTEGER32, CiA 402) -4300000 read 4290667296 in the SDO
    record and the decoded frame, while a TPDO carrying it decoded it signed; a reviewer
    saw a far positive target. 6041h (UNSIGNED16) and unsigned P-parameters stay unsigned."""
    from hil.protocol.canopen import describe_frame

    req = bytes.fromhex("237A6000") + (-4_300_000).to_bytes(4, "little", signed=True)
    p = SdoPairing()
    assert p.feed(0x601, req, 0) == []
    (txn,) = p.feed(0x581, bytes.fromhex("607A600000000000"), 300)
    assert txn["object"] == "607Ah:00" and txn["value"] == -4_300_000
    assert txn["data"] == "2063beff"  # the bytes as on the wire
    assert describe_frame(0x601, req)["value"] == -4_300_000
    # 60C2h:02 interpolation time index (INTEGER8) -4: 2F C2 60 02 FC
    assert describe_frame(0x601, bytes.fromhex("2FC26002FC000000"))["value"] == -4
    # 60FFh target velocity -600 in an upload reply
    p.feed(0x601, bytes.fromhex("40FF600000000000"), 1_000)
    (up,) = p.feed(0x581, bytes.fromhex("43FF6000A8FDFFFF"), 1_300)
    assert up["value"] == -600
    # unsigned objects keep their unsigned reading
    assert describe_frame(0x581, bytes.fromhex("4B416000FFFF0000"))["statusword"] == 0xFFFF
    assert p.feed(0x601, bytes.fromhex("2B01210018FC0000"), 2_000) == []
    (u,) = p.feed(0x581, bytes.fromhex("6001210000000000"), 2_300)
    assert u["value"] == 0xFC18  # 2101h P1.001 control mode: 0..4383, unsigned


def test_a_signed_p_parameter_reads_signed_in_the_sdo_record():
    """P-parameters over SDO (2xxxh, L18154-18156) read unsigned in the record: P1.043 = -50
    (brake-off delay, -1000..1000) read 65486, P6.001 = -4300000 (PR#0 data) 4290667296.
    Signed where the chapter 8 table's range is."""
    from functools import partial

    from hil.protocol.canopen import describe_frame as describe
    from hil.record.sdo_pairing import signed_parameter_objects

    describe_frame = partial(describe, signed_params=signed_parameter_objects())  # the recorder's
    p = SdoPairing()
    assert p.feed(0x601, bytes.fromhex("2B2B2100CEFF0000"), 0) == []  # 212Bh = P1.043, 2 bytes
    (txn,) = p.feed(0x581, bytes.fromhex("602B210000000000"), 300)
    assert txn["object"] == "212Bh:00" and txn["value"] == -50
    req = bytes.fromhex("23012600") + (-4_300_000).to_bytes(4, "little", signed=True)
    assert describe_frame(0x601, req)["value"] == -4_300_000  # 2601h = P6.001
    p.feed(0x601, bytes.fromhex("4001260000000000"), 1_000)
    (up,) = p.feed(0x581, bytes.fromhex("4301260020 63BEFF".replace(" ", "")), 1_300)
    assert up["value"] == -4_300_000
    # P1.044 (212Ch, 1..536870911) stays unsigned
    assert describe_frame(0x601, bytes.fromhex("232C2100FFFFFFFF"))["value"] == 0xFFFFFFFF


def test_the_recorder_reads_a_signed_p_parameter_signed(tmp_path):
    """The same on a recording: the decoded frame and the SDO transaction of P1.043 = -50."""
    p = tmp_path / "r.mcap"
    with Recorder(p) as rec:
        rec.can("can0", frame(0x601, "2B2B2100CEFF0000"), "tx", T0, None)
        rec.can("can0", frame(0x581, "602B210000000000"), "rx", T0 + 300_000, None)
    assert rec.errors == 0, rec.last_error
    r = Recording.open(p)
    req = [o for *_x, o in r.messages(topics.canopen("can0")) if o["dir"] == "tx"]
    assert req[0]["value"] == -50
    (txn,) = [o for *_x, o in r.messages(topics.canopen_sdo("can0"))]
    assert txn["object"] == "212Bh:00" and txn["value"] == -50

def test_sdo_upload_2_bytes_and_abort():
    # upload request 40h, reply 4Bh = 2 bytes (L17003-L17016); abort 80h with code
    # 06020000h "object does not exist" (L17024-L17042)
    p = SdoPairing()
    p.feed(0x601, bytes.fromhex("4041600000000000"), 0)
    (txn,) = p.feed(0x581, bytes.fromhex("4B41600037020000"), 500)
    assert txn["access"] == "upload" and txn["transfer"] == "expedited"
    assert txn["value"] == 0x0237 and txn["size"] == 2
    p.feed(0x601, bytes.fromhex("40FE600000000000"), 1_000)
    (ab,) = p.feed(0x581, bytes.fromhex("80FE600000000206"), 1_700)
    assert ab["status"] == "abort" and ab["abort_code"] == 0x06020000
    assert ab["abort_by"] == "server" and ab["latency_ns"] == 700


def test_sdo_segmented_upload_and_unanswered():
    p = SdoPairing()
    p.feed(0x605, bytes.fromhex("4008100000000000"), 0)  # 1008h device name
    assert p.feed(0x585, bytes.fromhex("41081000 0A000000".replace(" ", "")), 10) == []
    p.feed(0x605, bytes.fromhex("6000000000000000"), 20)
    assert p.feed(0x585, bytes.fromhex("00") + b"ASDA-A3", 30) == []
    p.feed(0x605, bytes.fromhex("7000000000000000"), 40)
    (txn,) = p.feed(0x585, bytes.fromhex("1B") + b"-E\x00\x00\x00\x00\x00", 50)
    assert bytes.fromhex(txn["data"]) == b"ASDA-A3-E" and txn["transfer"] == "segmented"
    assert txn["latency_ns"] == 50 and txn["frames"] == 6
    p.feed(0x605, bytes.fromhex("4041600000000000"), 100)
    (timeout,) = p.feed(0x605, bytes.fromhex("4041600000000000"), 200)
    assert timeout["status"] == "timeout"
    (left,) = p.pending()
    assert left["status"] == "timeout" and left["t_request"] == 200


@pytest.mark.parametrize("data", ["", "60", "4B41", "FF" * 8])
def test_sdo_malformed_frames_are_errors_not_crashes(data):
    p = SdoPairing()
    out = p.feed(0x581, bytes.fromhex(data), 0) + p.feed(0x601, bytes.fromhex(data), 1)
    assert all(r["status"] in ("error", "abort", "timeout") for r in out)


def test_modbus_pairing_manual_e3_rtu_and_ascii():
    # E3 request/response (L15785-L15863), both framings
    p = ModbusPairing()
    req, un = p.feed(bytes.fromhex("011001120002040BB80000FCEB"), "rtu", "tx", 0)
    assert req == {"role": "request", "unit": 1, "function": 0x10} and un == []
    rsp, _ = p.feed(bytes.fromhex("011001120002E031"), "rtu", "rx", 4_000_000)
    assert rsp["role"] == "response" and rsp["rtt_ns"] == 4_000_000
    req, _ = p.feed(b":011001120002040BB8000013\r\n", "ascii", "tx", 0)
    rsp, _ = p.feed(b":011001120002DA\r\n", "ascii", "rx", 9)
    assert rsp["rtt_us"] == 0.009


def test_modbus_exception_and_unanswered():
    p = ModbusPairing()
    body = bytes.fromhex("0103020000 02".replace(" ", ""))
    p.feed(body + crc16(body).to_bytes(2, "little"), "rtu", "tx", 0)
    exc = bytes([1, 0x83, 0x02])
    rsp, _ = p.feed(exc + crc16(exc).to_bytes(2, "little"), "rtu", "rx", 10)
    assert rsp["role"] == "exception" and rsp["exception_code"] == 2
    p.feed(body + crc16(body).to_bytes(2, "little"), "rtu", "tx", 20)
    _req, un = p.feed(body + crc16(body).to_bytes(2, "little"), "rtu", "tx", 30)
    assert un[0]["unanswered"] and un[0]["t_request"] == 20


def test_modbus_crc_examples_from_the_manual():
    # CRC 3794H sent as 94 37 for 01 03 01 01 00 02 (L15911-L15920)
    assert crc16(bytes.fromhex("010301010002")) == 0x3794
    # LRC example :7F0305C40001B4 (L15873-L15895)
    assert pdu_of(b":7F0305C40001B4\r\n", "ascii") == bytes.fromhex("7F0305C40001")
    with pytest.raises(ValueError, match="CRC mismatch"):
        pdu_of(bytes.fromhex("0103010100029437"[:-2] + "00"), "rtu")
    with pytest.raises(ValueError, match="LRC mismatch"):
        pdu_of(b":7F0305C40001B5\r\n", "ascii")


def _fuzz(rec: Recorder, seed: int) -> int:
    rng = random.Random(seed)
    n = 0
    for i in range(400):
        cid = rng.choice(
            [0x000, 0x080, 0x081, 0x181, 0x581, 0x601, 0x701, 0x7FF, rng.randrange(0x800)]
        )
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        rec.can("can0", frame(cid, data), rng.choice(["rx", "tx", 'we"ird']), T0 + i, None)
        junk = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 30)))
        if rng.random() < 0.3:
            junk = b":" + junk.hex().encode()[:20] + b"\r\n"
        rec.serial("com1", junk, rng.choice(["rx", "tx"]), T0 + i, None)
        n += 1
    return n


def test_malformed_input_never_crashes_the_recorder(tmp_path):
    p = tmp_path / "fuzz.mcap"
    with Recorder(p) as rec:
        n = _fuzz(rec, 1)
    assert rec.errors == 0, rec.last_error
    r = Recording.open(p)
    counts = r.counts()
    assert counts[topics.can_raw("can0")] == n
    assert counts[topics.rs485_raw("com1")] == n
    assert counts[topics.modbus("com1")] > 0  # chunks of one direction may merge
    for *_x, o in r.messages(topics.modbus("com1")):
        assert o["role"] in ("request", "response", "exception", "unknown")
        if o["role"] == "unknown":
            assert o["error"]


def test_a_raising_decoder_becomes_an_error_field(tmp_path, monkeypatch):
    def boom(can_id, data, **kw):
        raise RuntimeError(f"cannot decode {can_id:x}")

    def boom_adu(data, mode):
        raise RuntimeError("adu")

    monkeypatch.setattr(
        recorder_mod, "_load", lambda m, a: (boom if "canopen" in m else boom_adu, f"{m}.{a}")
    )
    p = tmp_path / "boom.mcap"
    with Recorder(p) as rec:
        rec.can("can0", frame(0x181, "01"), "rx", T0, None)
        rec.serial("com1", bytes.fromhex("011001120002E031"), "rx", T0, None)
    assert rec.errors == 0
    r = Recording.open(p)
    (dec,) = [o for *_x, o in r.messages(topics.canopen("can0"))]
    assert dec["dir"] == "rx" and "cannot decode 181" in dec["error"]
    mb, unanswered = [o for *_x, o in r.messages(topics.modbus("com1"))]
    assert unanswered["unanswered"]  # closed at the end of the recording
    assert "describe_adu failed" in mb["adu"]["error"]


def test_missing_decoders_are_skipped(tmp_path, monkeypatch):
    monkeypatch.setattr(recorder_mod, "_load", lambda m, a: (None, "missing (test)"))
    p = tmp_path / "nodec.mcap"
    with Recorder(p) as rec:
        rec.can("can0", frame(0x60A, "23012700E0930400"), "tx", T0, None)
        rec.can("can0", frame(0x58A, "6001270000000000"), "rx", T0 + 5, None)
        rec.serial("com1", bytes.fromhex("011001120002E031"), "rx", T0, None)
    r = Recording.open(p)
    assert topics.canopen("can0") not in r.topics()
    assert r.counts()[topics.canopen_sdo("can0")] == 1  # pairing is our own
    mb = next(o for *_x, o in r.messages(topics.modbus("com1")))
    assert "adu" not in mb and mb["role"] == "request"
    assert "missing" in r.metadata()["hil.close"]["decoders"]


def test_decoded_canopen_per_frame(tmp_path):
    p = tmp_path / "co.mcap"
    with Recorder(p) as rec:
        for i in range(3):
            rec.can("can0", frame(0x080, b""), "tx", T0 + i, None)  # SYNC
        rec.can("can0", frame(0x70A, "05"), "rx", T0 + 9, None)  # heartbeat
    dec = [o for *_x, o in Recording.open(p).messages(topics.canopen("can0"))]
    assert len(dec) == 4 and all("error" not in o for o in dec)
    assert [o["dir"] for o in dec] == ["tx", "tx", "tx", "rx"]


def test_split_rtu_frames_are_reassembled(tmp_path):
    # E3 request split over two reads, response in one (L15838-L15863)
    p = tmp_path / "split.mcap"
    req = bytes.fromhex("011001120002040BB80000FCEB")
    with Recorder(p) as rec:
        rec.serial("com1", req[:5], "tx", T0, None)
        rec.serial("com1", req[5:], "tx", T0 + 1_000, None)
        rec.serial("com1", bytes.fromhex("011001120002E031"), "rx", T0 + 3_000_000, None)
        rec.serial("com1", bytes.fromhex("0110"), "tx", T0 + 4_000_000, None)  # cut short
    r = Recording.open(p)
    assert r.counts()[topics.rs485_raw("com1")] == 4
    mb = [o for *_x, o in r.messages(topics.modbus("com1"))]
    assert [m["role"] for m in mb] == ["request", "response", "unknown"]
    assert mb[0]["raw"] == req.hex() and mb[1]["rtt_ns"] == 3_000_000
    assert "too short" in mb[2]["error"]


def test_pdo_fast_path_equals_the_decoder(tmp_path) -> None:
    """Changing PDO payloads use a cached prefix; the result must equal describe_frame."""
    import can

    from hil.protocol.canopen import describe_frame
    from hil.record.reader import Recording
    from hil.record.recorder import Recorder

    frames = [can.Message(arbitration_id=0x185, data=bytes([i, i + 1, 2, 3, 4, 5, 6, 7]),
                          is_extended_id=False) for i in range(50)]
    frames.append(can.Message(arbitration_id=0x185, data=bytes([1, 2]), is_extended_id=False))
    path = tmp_path / "pdo.mcap"
    with Recorder(path) as rec:
        for i, f in enumerate(frames):
            rec.can("can0", f, "rx", 1_000_000 * (i + 1), None)
    got = [m for _t, _l, _p, m in Recording.open(path).messages(["/canopen/can0"])]
    assert len(got) == len(frames)
    for f, m in zip(frames, got, strict=True):
        m.pop("dir")
        assert m == describe_frame(f.arbitration_id, bytes(f.data))


def test_raw_and_decoded_frames_read_back_as_sent(tmp_path) -> None:
    """The raw frame's JSON (cached per frame shape around its data) and the decoded CANopen
    text (cached per PDO, direction included) read back as each frame's own fields and as
    `describe_frame` says, for random shapes, directions and repeated frames."""
    import can

    from hil.protocol.canopen import describe_frame

    rng = random.Random(29)
    sent = []
    for _ in range(3000):
        ext, rtr = rng.random() < 0.2, rng.random() < 0.1
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        cid = rng.choice([0x80, 0x185, 0x185, 0x205, 0x601, 0x581, 0x70A,
                          rng.randrange(1 << (29 if ext else 11))])
        f = can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=rtr,
                        is_error_frame=rng.random() < 0.03, is_fd=rng.random() < 0.05,
                        data=data, dlc=rng.randrange(9) if rtr else len(data))
        sent.append((f, rng.choice(["rx", "tx", 'odd "dir"'])))
    path = tmp_path / "shapes.mcap"
    with Recorder(path) as rec:
        for i, (f, d) in enumerate(sent):
            rec.can("can0", f, d, T0 + i, None)
    r = Recording.open(path)
    raw = [o for *_x, o in r.messages(topics.can_raw("can0"))]
    dec = iter(o for *_x, o in r.messages(topics.canopen("can0")))
    assert len(raw) == len(sent)
    for (f, d), o in zip(sent, raw, strict=True):
        assert o == {"id": f.arbitration_id, "ext": f.is_extended_id, "rtr": f.is_remote_frame,
                     "err": f.is_error_frame, "fd": f.is_fd, "brs": False, "esi": False,
                     "dlc": f.dlc, "data": bytes(f.data).hex(), "dir": d}
        if f.is_extended_id or f.is_error_frame:
            continue  # CANopen uses 11-bit identifiers: no decoded message
        m = next(dec)
        assert m.pop("dir") == d
        kw = {"remote": True} if f.is_remote_frame else {}
        assert m == describe_frame(f.arbitration_id, bytes(f.data), **kw)
    assert next(dec, None) is None
