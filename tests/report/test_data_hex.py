"""The report shows CANopen ids and objects in hex, as CANopen people read them."""

from __future__ import annotations

from hil.report.data import _brief


def test_cob_ids_and_indexes_are_hex() -> None:
    text = _brief({"dir": "tx", "kind": "sdo_rx", "cob_id": 1537, "index": 24640, "sub": 0,
                   "value": 15})
    assert "cob_id=601h" in text and "index=6040h" in text and "value=15" in text
    assert "1537" not in text and "24640" not in text
