"""`json_plain`: the recorder's mirror holds a payload's dict only where decoding its JSON
gives back exactly that dict, types included (docs/recording.md, the live checks)."""

from __future__ import annotations

import enum
import json
import sys

import pytest

from hil.record.recorder import dumps, dumps_checked, json_plain


class Mode(enum.Enum):
    PP = 1


class Count(int):
    pass


PLAIN = [
    {},
    {"t": 1, "state": "OPERATION_ENABLED", "speed_rpm": 12.5, "servo_on": True, "x": None},
    {"di": [True, False, 1, 0.5, "a", None], "alarms": [], "n": -(2**80)},
]
NOT_PLAIN = [
    {"mode": Mode.PP},
    {"t": (1, 2)},
    {"di": [True, (1,)]},
    {"di": [Count(3)]},
    {"n": Count(3)},
    {1: "int key"},
    {"nested": {"a": 1}},
    {"di": [[1]]},
]


@pytest.mark.parametrize("payload", PLAIN)
@pytest.mark.parametrize("encoded", [False, True])
def test_a_plain_payload_is_copied_and_decodes_to_itself(payload, encoded) -> None:
    data, ok = dumps_checked(payload)
    assert ok and data == dumps(payload)
    got = json_plain(payload, encoded)
    assert got == payload == json.loads(data)
    assert got is not payload
    for k, v in payload.items():  # lists are copies: a later change to one stays out
        if isinstance(v, list):
            assert got[k] is not v
    assert [type(v) for v in got.values()] == [type(v) for v in json.loads(data).values()]


@pytest.mark.parametrize("payload", NOT_PLAIN)
@pytest.mark.parametrize("encoded", [False, True])
def test_a_payload_json_changes_is_not_mirrored(payload, encoded) -> None:
    assert json_plain(payload, encoded) is None


def test_an_int_without_a_decimal_form_is_an_error_object_not_mirrored() -> None:
    limit = getattr(sys, "get_int_max_str_digits", lambda: 0)()
    if not limit:
        pytest.skip("no int-to-str digit limit in this Python")
    huge = 10 ** (limit + 10)
    for payload in ({"n": huge}, {"di": [1, huge]}):
        data, ok = dumps_checked(payload)
        assert not ok and "error" in json.loads(data)
        assert json_plain(payload) is None  # without the encoder's word, it checks itself
