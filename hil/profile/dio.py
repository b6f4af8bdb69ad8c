"""DI/DO function codes of the A3 as data: tables 8.1 / 8.2 and the mapping parameters.

Mapping parameter layout (L9238-9256, L9323-9339): low byte YX = function code (table 8.1 /
8.2), digit Z = contact: 0 = b (NC), 1 = a (NO). The DI/DO logic is `hil.model.dio.DigitalIO`.
"""

from __future__ import annotations

from dataclasses import dataclass

from hil.profile.errors import UnknownFunction


@dataclass(frozen=True, slots=True)
class Function:
    code: int
    symbol: str
    trigger: str  # "level" | "rising" | "both" ...
    line: str  # manual line(s)


def _table(rows: list[tuple[int, str, str, str]]) -> dict[int, Function]:
    return {code: Function(code, sym, trig, line) for code, sym, trig, line in rows}


# Table 8.1, DI functions (L15075-15255); 0 = DI disabled (L15255).
DI_FUNCTIONS: dict[int, Function] = _table(
    [
        (0x01, "SON", "level", "L15079"),
        (0x02, "ARST", "rising", "L15082"),
        (0x03, "GAINUP", "level", "L15085"),
        (0x04, "CCLR", "rising/level", "L15088"),
        (0x05, "ZCLAMP", "level", "L15091"),
        (0x06, "CMDINV", "level", "L15094"),
        (0x08, "CTRG", "rising", "L15098"),
        (0x09, "TRQLM", "level", "L15101"),
        (0x0A, "CTRY", "rising", "L15104"),
        (0x0C, "VPL", "level", "L15107"),
        (0x0D, "VPRS", "level", "L15113"),
        (0x0E, "FEC", "rising", "L15117"),
        (0x10, "SPDLM", "level", "L15121"),
        (0x11, "POS0", "level", "L15123"),
        (0x12, "POS1", "level", "L15125"),
        (0x13, "POS2", "level", "L15127"),
        (0x1A, "POS3", "level", "L15129"),
        (0x1B, "POS4", "level", "L15130"),
        (0x1C, "POS5", "level", "L15131"),
        (0x1E, "POS6", "level", "L15133"),
        (0x1D, "ABSE", "level", "L15137"),
        (0x1F, "ABSC", "rising", "L15141"),
        (0x14, "SPD0", "level", "L15151"),
        (0x15, "SPD1", "level", "L15155"),
        (0x16, "TCM0", "level", "L15162"),
        (0x17, "TCM1", "level", "L15165"),
        (0x18, "S-P", "level", "L15172"),
        (0x19, "S-T", "level", "L15176"),
        (0x20, "T-P", "level", "L15180"),
        (0x21, "EMGS", "level", "L15184"),
        (0x22, "NL", "level", "L15188"),
        (0x23, "PL", "level", "L15191"),
        (0x24, "ORGP", "both", "L15194"),
        (0x27, "SHOM", "rising", "L15197"),
        (0x2B, "PT-PR", "level", "L15200"),
        (0x35, "ALGN", "rising", "L15203"),
        (0x36, "CAM", "both", "L15206"),
        (0x37, "JOGU", "level", "L15209"),
        (0x38, "JOGD", "level", "L15212"),
        (0x39, "EV1", "both", "L15219"),
        (0x3A, "EV2", "both", "L15224"),
        (0x3B, "EV3", "both", "L15229"),
        (0x3C, "EV4", "both", "L15234"),
        (0x43, "GNUM0", "level", "L15239"),
        (0x44, "GNUM1", "level", "L15239"),
        (0x45, "INHP", "level", "L15244"),
        (0x46, "STP", "rising", "L15249"),
        (0x47, "PFQS", "rising", "L15253"),
    ]
)
# Table 8.2, DO functions (L15259-15415); 0 = DO disabled (L15405).
DO_FUNCTIONS: dict[int, Function] = _table(
    [
        (0x01, "SRDY", "level", "L15263"),
        (0x02, "SON", "level", "L15266"),
        (0x03, "ZSPD", "level", "L15269"),
        (0x04, "TSPD", "level", "L15272"),
        (0x05, "TPOS", "level", "L15275"),
        (0x06, "TQL", "level", "L15278"),
        (0x07, "ALRM", "level", "L15282"),
        (0x08, "BRKR", "level", "L15286"),
        (0x09, "HOME", "level", "L15290"),
        (0x0D, "ABSW", "level", "L15294"),
        (0x0E, "IDXD", "level", "L15298"),
        (0x10, "OLW", "level", "L15304"),
        (0x11, "WARN", "level", "L15307"),
        (0x12, "OVF", "level", "L15310"),
        (0x13, "SNL", "level", "L15313"),
        (0x14, "SPL", "level", "L15316"),
        (0x15, "Cmd_OK", "level", "L15319"),
        (0x16, "CAP_OK", "level", "L15323"),
        (0x17, "MC_OK", "level", "L15326"),
        (0x18, "CAM_AREA1", "level", "L15329"),
        (0x19, "SP_OK", "level", "L15332"),
        (0x1A, "CAM_AREA2", "level", "L15335"),
        (0x2C, "Zon1", "level", "L15336-15347"),
        (0x2D, "Zon2", "level", "L15336-15347"),
        (0x2E, "Zon3", "level", "L15336-15347"),
        (0x2F, "Zon4", "level", "L15336-15347"),
        *[(0x30 + n, f"SPO_{n:X}", "level", "L15353-15403") for n in range(16)],
    ]
)

DI_SYMBOLS = {f.symbol: f.code for f in DI_FUNCTIONS.values()}
DO_SYMBOLS = {f.symbol: f.code for f in DO_FUNCTIONS.values()}

# Mapping parameters: DI1-DI8, DI9-DI10, VDI11-VDI13 (L9238, L9558-9594).
DI_PARAMS = (
    "P2.010", "P2.011", "P2.012", "P2.013", "P2.014", "P2.015", "P2.016", "P2.017",
    "P2.036", "P2.037", "P2.038", "P2.039", "P2.040",
)  # fmt: skip
DO_PARAMS = ("P2.018", "P2.019", "P2.020", "P2.021", "P2.022", "P2.041")
N_PHYSICAL_DI = 10  # DI1-DI10, the physical inputs (VDI11-13 are virtual)
# A PLC's pulse line on a virtual bench without `pulse_wiring:`, from seed 001's example 3
# (001:120): DOG X0, PG0 X4 (here the OZ messages), CLR Y8; the stroke limits on X1 / X2;
# CLR drives DI2, the factory CCLR input (P2.011 = 0x0104, L1866).
DEFAULT_PULSE_WIRING: dict[str, str] = {"DOG": "X0", "NL": "X1", "PL": "X2", "Y8": "DI2"}
N_DI = len(DI_PARAMS)  # 13 incl. VDI11-13
N_DO = len(DO_PARAMS)


def decode_mapping(kind: str, value: int, where: str) -> tuple[int, bool]:
    """(function code, a_contact) from a P2.0xx value; raises UnknownFunction naming `where`."""
    code = value & 0xFF
    table = DI_FUNCTIONS if kind == "DI" else DO_FUNCTIONS
    if code and code not in table:
        raise UnknownFunction(kind, code, where)
    return code, bool((value >> 8) & 0xF)


# The DI/DO defaults of each control mode (§3.3.4 tables L1862-1913), which P1.001.U = 1 loads
# at the power-up where it is in effect (L7811-7813, note L1887). DI1-DI8 (P2.010-P2.017) by
# P1.001's mode byte; "-" is 0 (no function); NL, PL and EMGS b-contact and the others
# a-contact, as the factory values (P2.015-P2.017 = 0x0022/0x0023/0x0021, P2.010 = 0x0101).
# The CANopen (0x0C), DMCNET (0x0B) and PT-PR (0x0D-0x0F) modes have no DI column.
_B_CONTACT = frozenset({0x21, 0x22, 0x23})
_DI_COLUMNS: dict[tuple[int, ...], tuple[int, ...]] = {
    (0x00,): (0x01, 0x04, 0x16, 0x17, 0x02, 0x22, 0x23, 0x21),  # PT
    (0x01,): (0x01, 0x08, 0x11, 0x12, 0x02, 0x22, 0x23, 0x21),  # PR
    (0x02, 0x04): (0x01, 0x09, 0x14, 0x15, 0x02, 0x22, 0x23, 0x21),  # S / Sz
    (0x03, 0x05): (0x01, 0x10, 0x16, 0x17, 0x02, 0x22, 0x23, 0x21),  # T / Tz
    (0x06,): (0x01, 0x04, 0x14, 0x15, 0x00, 0x00, 0x18, 0x21),  # PT-S
    (0x07,): (0x01, 0x04, 0x16, 0x17, 0x00, 0x00, 0x20, 0x21),  # PT-T
    (0x08,): (0x01, 0x08, 0x11, 0x12, 0x14, 0x15, 0x18, 0x21),  # PR-S
    (0x09,): (0x01, 0x08, 0x11, 0x12, 0x16, 0x17, 0x20, 0x21),  # PR-T
    (0x0A,): (0x01, 0x00, 0x14, 0x15, 0x16, 0x17, 0x23, 0x21),  # S-T
}
# DO1-DO5 (P2.018-P2.022): "PT/PR/通訊模式" DO3 HOME, "速度/扭矩模式" DO3 TSPD; a mixed mode
# by its first mode (S-T: speed)
_DO_POSITION = (0x0101, 0x0103, 0x0109, 0x0105, 0x0007)
_DO_SPEED = (0x0101, 0x0103, 0x0104, 0x0105, 0x0007)
_SPEED_TORQUE = frozenset({0x02, 0x03, 0x04, 0x05, 0x0A})


def mode_dio_defaults(mode: int) -> dict[str, int]:
    """P2.010-P2.022 as the tables L1862-1913 give them for P1.001's mode byte `mode`
    (the DIs only where the table has a column)."""
    out: dict[str, int] = {}
    for modes, codes in _DI_COLUMNS.items():
        if mode in modes:
            for param, code in zip(DI_PARAMS, codes, strict=False):
                out[param] = code if code in _B_CONTACT or not code else 0x0100 | code
    dos = _DO_SPEED if mode in _SPEED_TORQUE else _DO_POSITION
    out.update(zip(DO_PARAMS, dos, strict=False))
    return out
