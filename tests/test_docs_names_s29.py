"""Every `hil.x.y` Python name the README and docs/ give resolves (helper-122: the docs named
`hil.transport.open_can`, which is `hil.transport.can_bus.open_can`). A name whose first two
parts are a recording's metadata record (`hil.bench.deviations`) is a key, not code."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METADATA = {"hil.run", "hil.bench", "hil.clock", "hil.result", "hil.dut", "hil.close",
            "hil.versions", "hil.plan", "hil.repair"}


def _resolves(name: str) -> bool | None:
    """True / False; None when no module of two parts or more begins it (a metadata or
    topic name such as `hil.run`)."""
    parts = name.split(".")
    for i in range(len(parts), 1, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return None


def test_the_python_names_the_docs_give_exist() -> None:
    bad = []
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        for m in re.finditer(r"`(hil(?:\.[A-Za-z_][A-Za-z0-9_]*)+)", text):
            name = m.group(1)
            if _resolves(name) is False and ".".join(name.split(".")[:2]) not in METADATA:
                bad.append(f"{doc.name}: {name}")
    assert not bad, bad
