"""Fixtures for the recording tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from rec_helpers import EP_TEXT, canio_registered


@pytest.fixture
def canio_entry_points(tmp_path_factory, monkeypatch) -> Path | None:
    """Make the `.mcap` python-can plugin visible through real entry points.

    pyproject.toml declares them; an editable install made before they were added does not
    list them, so this puts a stand-in dist-info on sys.path (and returns its directory for
    subprocesses' PYTHONPATH). Returns None when the install already has them.
    """
    if canio_registered():
        return None
    d = tmp_path_factory.mktemp("ep")
    info = d / "hil_canio_ep-0.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: hil-canio-ep\nVersion: 0.0\n")
    (info / "entry_points.txt").write_text(EP_TEXT)
    monkeypatch.syspath_prepend(str(d))
    assert canio_registered()
    return d
