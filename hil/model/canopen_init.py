"""P3.012.Z: parameters the CANopen mode loads at power-up / communication reset.

P3.012.Z = 0: "after a power cycle or a communication reset, the P parameters below are
loaded with the CANopen / DMCNET values"; Z = 1: they keep their EEPROM setting
(L10729-10745, repeated in §12.1 step 4, L16847-16855). Applies in CANopen mode
(P1.001 = 0x0C, L16842). The home offset (607Ch, "HM 模式使用") is loaded with 0 too.

This settles the 212Ch (P1.044) default question: the OD example says 212Ch defaults to 1
(L18175-18184) while P1.044 defaults to 16777216 (L8518): both are right, 1 is what a CANopen
drive with P3.012.Z = 0 reads after power-up.
"""

from __future__ import annotations

from hil.model.params import ParameterStore
from hil.profile.canopen_init import CANOPEN_INIT_VALUES, CANOPEN_MODE, HOME_OFFSET_INIT

__all__ = ["CANOPEN_INIT_VALUES", "CANOPEN_MODE", "HOME_OFFSET_INIT"]


def canopen_init_applies(params: ParameterStore) -> bool:
    """CANopen mode (P1.001 = 0x0C, in effect) and P3.012.Z = 0."""
    mode = params.get("P1.001") & 0xFF
    z = (params.get("P3.012") >> 8) & 0xF
    return mode == CANOPEN_MODE and z == 0


def load_canopen_init(params: ParameterStore) -> bool:
    """Load the table's values when P3.012.Z = 0 in CANopen mode; True if it did."""
    if not canopen_init_applies(params):
        return False
    for name, value in CANOPEN_INIT_VALUES.items():
        params.set_internal(name, value)
    return True
