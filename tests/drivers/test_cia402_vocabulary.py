"""One home for the CiA 402 / SDO constants (hil/protocol), read by model, driver, plan, gateway."""

from __future__ import annotations

from hil import safety
from hil.drivers import cia402 as driver
from hil.gateway import gateway
from hil.model import cia402 as model_cia402
from hil.model import drive
from hil.plan.kinds import fields as steps
from hil.protocol import canopen as P
from hil.protocol import cia402 as P402
from hil.record import sdo_pairing


def test_statusword_masks_are_the_manuals():
    """canopen's State402 masks equal the manual's state table (L18321-L18331)."""
    assert driver.STATES == {
        "NOT READY TO SWITCH ON": (0x4F, 0x00),
        "SWITCH ON DISABLED": (0x4F, 0x40),
        "READY TO SWITCH ON": (0x6F, 0x21),
        "SWITCHED ON": (0x6F, 0x23),
        "OPERATION ENABLED": (0x6F, 0x27),
        "QUICK STOP ACTIVE": (0x6F, 0x07),
        "FAULT REACTION ACTIVE": (0x4F, 0x0F),
        "FAULT": (0x4F, 0x08),
    }
    assert driver.decode_state(0x0637) == "OPERATION ENABLED"


def test_controlword_and_modes_have_one_home():
    """Controlword commands L18272-L18281, 6060h modes L18375-L18381."""
    assert P402.CONTROLWORD["shutdown"] == 0x06 and P402.CONTROLWORD["quick_stop"] == 0x02
    assert safety.CONTROLWORD is P402.CONTROLWORD  # the one safe-state routine (hil/safety.py)
    assert driver.MODES is P402.MODES and drive.MODE_NAMES is P402.MODE_NAMES
    assert (model_cia402.PP, model_cia402.HM, model_cia402.IP) == (1, 6, 7)
    assert set(steps.MODES) < set(P402.MODES)


def test_sdo_cob_ids_are_named_from_the_client_side():
    """The client requests on 0x600 + node and the server responds on 0x580 + node."""
    assert (P.SDO_REQUEST, P.SDO_RESPONSE) == (0x600, 0x580)
    assert P.classify(0x60A) == ("sdo_rx", 10) and P.classify(0x58A) == ("sdo_tx", 10)
    assert not hasattr(sdo_pairing, "TX_BASE") and not hasattr(gateway, "SDO_TX")
    pairing = sdo_pairing.SdoPairing()
    assert pairing.feed(0x60A, P.sdo_upload_request(0x6041, 0), 0) == []
    (txn,) = pairing.feed(0x58A, P.sdo_expedited_upload_response(0x6041, 0, b"\x37\x06"), 5)
    assert (txn["node"], txn["value"], txn["latency_ns"]) == (10, 0x0637, 5)
