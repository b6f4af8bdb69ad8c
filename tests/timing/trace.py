"""Build synthetic SignalSources for timing tests (times in ms, converted to ns)."""

from __future__ import annotations

from typing import Any

from hil.timing.source import MemorySource

MS = 1_000_000
STATE = "/drive/drive1/state"
PARAMS = "/drive/drive1/params"


def dio(line: str) -> str:
    return f"/dio/drive1/{line}"


def source(series: dict[tuple[str, str], list[tuple[float, Any]]],
           params: dict[str, Any] | None = None,
           resolutions: dict[str, int] | None = None) -> MemorySource:
    """series: {(topic, field): [(t_ms, value), ...]}; params recorded at t = 0."""
    ns = {k: [(round(t * MS), v) for t, v in lst] for k, lst in series.items()}
    return MemorySource.from_series(ns, resolutions=resolutions, params=params,
                                    params_topic=PARAMS)


def by_name(verdicts, name: str):
    out = [v for v in verdicts if v.constraint == name]
    assert out, f"no verdict for {name!r}: {[v.constraint for v in verdicts]}"
    return out
