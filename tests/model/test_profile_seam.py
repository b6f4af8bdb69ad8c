"""hil/profile is the A3 as data: the model reads it, and it reads nothing of the model or a bus."""

from __future__ import annotations

import subprocess
import sys

CHECK = """
import sys
import hil.model.drive, hil.profile.params, hil.profile.dio, hil.profile.alarms
bad = sorted(m for m in sys.modules if m.split('.')[0] in ('can', 'canopen', 'serial', 'zenoh'))
assert not bad, bad
"""

PURE = """
import sys
import hil.profile.params, hil.profile.dio, hil.profile.alarms
bad = sorted(m for m in sys.modules if m.startswith(('hil.model', 'hil.faces', 'can')))
assert not bad, bad
"""


def test_model_and_profile_tables_import_no_bus_library():
    subprocess.run([sys.executable, "-c", CHECK], check=True)


def test_profile_tables_import_nothing_of_the_model():
    subprocess.run([sys.executable, "-c", PURE], check=True)


def test_one_home_per_table():
    """The model uses the profile's objects, not copies (L9238 mapping params, table 8.1)."""
    from hil.model import dio, errors, params
    from hil.profile import dio as pdio
    from hil.profile import errors as perrors
    from hil.profile import params as pparams

    assert dio.DI_FUNCTIONS is pdio.DI_FUNCTIONS and dio.DI_PARAMS is pdio.DI_PARAMS
    assert params.ParamTable is pparams.ParamTable
    assert errors.UnknownParameter is perrors.UnknownParameter
