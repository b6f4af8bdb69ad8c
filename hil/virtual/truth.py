"""What a virtual bench adds to a run: sensor lines taken from the ground truth, and the
bench file a session opens with a plan's model options."""

from __future__ import annotations

import contextlib
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from hil import clock
from hil.bench.bench import Bench
from hil.model.drive import DEFAULT_SENSORS


class SensorTap:
    """The recorder as the virtual world sees it, plus the lines the bench mechanics drive.

    The virtual axis drives its own sensors (NL DI6, PL DI7, ORGP DI9: `DEFAULT_SENSORS`);
    the harness never sets ORGP and sets NL/PL only at rest, so their levels are taken from
    the ground truth (`di` of each `/drive/<name>/state` sample) and recorded on
    `/dio/<name>/DI<n>` when they change, stamped with the sample's own time."""

    def __init__(self, rec: Any) -> None:
        self._rec = rec
        self._lines = sorted(n for n, _kind in DEFAULT_SENSORS.values())
        self._last: dict[tuple[str, int], bool] = {}
        self._last_di: dict[str, list] = {}  # per drive, the DI levels of its last sample

    def __getattr__(self, name: str) -> Any:
        return getattr(self._rec, name)

    def drive_state(self, drive: str, state: Any, **kw: Any) -> None:
        self._rec.drive_state(drive, state, **kw)
        di = state.get("di") if isinstance(state, dict) else None
        if not isinstance(di, list | tuple):
            return
        if type(di) is list and self._last_di.get(drive) == di:
            return  # no level changed since the last sample (nearly every one at 1 kHz)
        self._last_di[drive] = list(di)
        for n in self._lines:
            if n > len(di):
                continue
            lv = bool(di[n - 1])
            if self._last.get((drive, n)) != lv:
                self._last[(drive, n)] = lv
                self._rec.dio(drive, f"DI{n}", lv, clock.time_ns(), kw.get("source_t"))


def bench_with_options(bench: Bench, options: dict[str, Any],
                       stack: contextlib.ExitStack) -> Bench:
    """The bench a session opens: a plan's model `options` merged into every virtual
    drive's (a subprocess bench gets them in a temporary copy of its file: `hil drive
    --bench` reads the file)."""
    if not options or not bench.virtual:
        return bench
    drives = {n: replace(d, options=dict(d.options) | options)
              for n, d in bench.drives.items()}
    out = replace(bench, drives=drives)
    if bench.process == "subprocess":
        data = yaml.safe_load(bench.text)
        for d in data.get("drives", {}).values():
            d["options"] = dict(d.get("options") or {}) | options
        tdir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="hil-plan-")))
        path = tdir / Path(bench.path or "bench.yaml").name
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
        out = replace(out, path=str(path), text=path.read_text(encoding="utf-8"))
    return out
