"""The checked-in EDS equals a fresh canopen `export_od` of hil.profile.od, and loads back."""

from __future__ import annotations

import canopen

from hil.profile.eds import generate_eds
from hil.profile.od import EDS_PATH, TYPE_CODES, ObjectDictionary, parameter_index


def test_checked_in_eds_is_fresh():
    assert EDS_PATH.read_text(encoding="utf-8") == generate_eds(), (
        "fixtures/drive/a3.eds is stale: run `python -m hil.profile.eds`"
    )


def test_eds_lists_every_object_with_its_default():
    """Every entry of the A3 dictionary comes back from the EDS with its type, access, PDO
    flag and default (COB-IDs relative to the node, L17877-L17885)."""
    od = canopen.import_od(str(EDS_PATH), node_id=10)
    entries = ObjectDictionary.a3().entries
    seen = set()
    for index in od:
        obj = od[index]
        subs = [obj] if isinstance(obj, canopen.objectdictionary.ODVariable) else obj.values()
        seen |= {(v.index, v.subindex) for v in subs}
    assert seen == set(entries)
    for (index, sub), e in entries.items():
        var = od[index] if e.object == "VAR" else od[index][sub]
        assert (var.data_type, var.access_type, var.pdo_mappable) == (
            TYPE_CODES[e.type], e.access, e.pdo), (index, sub)
        assert var.default == e.default_for(10), (index, sub)
    assert od[0x2509].default == -2147483648  # P5.009: a negative default survives


def test_canopen_import_od_reads_it():
    od = canopen.import_od(str(EDS_PATH), node_id=10)
    assert od[0x1000].default == 0x07020192  # L17482-L17508
    assert od[0x1018][1].default == 0x1DD and od[0x1018][2].default == 0x6000  # L17784/92
    assert od[0x1200][1].default == 0x60A and od[0x1200][2].default == 0x58A  # L17877-85
    assert od[0x1014].default == 0x8A  # L17704-L17708
    assert od[0x6502].default == 0x6D  # L19259
    assert od[0x6040].default == 0x0004  # L18212
    assert od[0x6061].access_type == "ro"  # ⚠ resolved, docs/manual-choices.md#canopen


def test_parameter_objects():
    # Pa.bc <=> 2aBCh, BC = bc in hex (L18156)
    assert parameter_index("P3.000") == 0x2300
    assert parameter_index("P1.044") == 0x212C
    assert parameter_index("P7.001") == 0x2701
    od = ObjectDictionary.a3()
    if (0x2300, 0) in od:  # a3_parameters.csv present
        assert od.get(0x2300, 0).type == "INTEGER16" and od.get(0x2300, 0).pdo
        assert od.get(0x212C, 0).type == "INTEGER32"


def test_eds_defaults_of_the_canopen_init_table():
    """212Ch "預設值 1" (L18175-18184) is the P3.012.Z = 0 init value (L10737-10745)."""
    od = canopen.import_od(str(EDS_PATH), node_id=10)
    assert od[0x212C].default == 1 and od[0x212D].default == 1  # P1.044 / P1.045
    assert od[0x2120].default == 0x0010  # P1.032
    assert od[0x2126].default == 100  # P1.038
    assert od[0x2223].default == 50331648  # P2.035
    assert od[0x2109].default == 1000  # P1.009 is not in the table: its own default
