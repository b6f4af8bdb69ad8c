"""P3.012.Z = 0: the values CANopen mode loads at power-up / communication reset (data).

The rule that applies them is the model's (hil/model/canopen_init.py); the table is here
because the object dictionary's defaults read it too (L10729-10745, L16847-16855).
"""

from __future__ import annotations

CANOPEN_MODE = 0x0C  # P1.001 low byte (L16842)

# Table "初始化時讀出的相關變數", column P3.012.Z = 0 (L10737-10745, L16847-16855).
CANOPEN_INIT_VALUES: dict[str, int] = {
    "P1.032": 0x0010,
    "P2.035": 50331648,
    "P1.047": 100,
    "P1.049": 0,
    "P1.038": 100,
    "P1.044": 1,
    "P1.045": 1,
}
HOME_OFFSET_INIT = 0  # 607Ch
