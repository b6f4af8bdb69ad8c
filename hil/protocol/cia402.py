"""CiA 402 vocabulary, once: controlword commands (6040h), modes of operation (6060h/6061h).

Pure (no bus import): the model, the driver, the plan checker, the safe state and the gateway
all read these. Statusword state masks are canopen's `State402.SW_MASK` (identical to the
manual's table, L18321-L18331); the driver, which runs on canopen, uses them from there.
"""

from __future__ import annotations

# Controlword commands (L18272-L18281). Low byte; bits 4-9 are mode specific.
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_FAULT_RESET = 0x0080  # rising edge of bit 7
CONTROLWORD: dict[str, int] = {
    "disable_voltage": CW_DISABLE_VOLTAGE,
    "quick_stop": CW_QUICK_STOP,
    "shutdown": CW_SHUTDOWN,
    "switch_on": CW_SWITCH_ON,
    "enable_operation": CW_ENABLE_OPERATION,
    "fault_reset": CW_FAULT_RESET,
}

# Modes of operation the A3 supports, 6060h/6061h values (L18375-L18381; 6502h = 0x6D).
MODES: dict[str, int] = {"PP": 1, "PV": 3, "PT": 4, "HM": 6, "IP": 7}
MODE_NAMES: dict[int, str] = {0: "", **{code: name for name, code in MODES.items()}}
