"""Judge a drive's CAPTURE against ground truth, with the B&R LATCH options (docs/capture.md).

The sensor's edges and the true axis position come from a recording:

* edges: on a virtual bench the model's `InputChanged` (DI7) or `ZPulse` events on
  `/drive/<d>/events` (exact model instants); otherwise the harness's own line
  `/dio/<d>/DI7` (its timestamps);
* true position: linear interpolation of a reference field at the edge (default
  `/drive/<d>/state` `position_puu`, the virtual world's ground truth; a real bench names its
  reference encoder channel). The uncertainty is what sampling leaves open: half a count of
  rounding, plus, when no sample sits at the edge, the larger distance from the interpolated
  value to the two samples around it.

The k-th trigger edge since the capture was armed is paired with the k-th captured value
(the drive latches every edge while armed). Options from seed 003 (B&R ACOPOS LATCH,
003:401-505): `window` accepts only edges whose true position lies in [min, max]
(LATCH_WINDOW1/2 around LATCH_WINDOW_POS); `width` rejects pulses narrower or wider than
the limits, in position units between the edge and the opposite edge (LATCH_EV_WIDTH_MIN/MAX,
types 2/3/5); `edges: first` judges only the first accepted edge, `every` each of them.
"""

from __future__ import annotations

import bisect
from dataclasses import asdict, dataclass
from typing import Any

from hil.record import topics
from hil.units import s32


@dataclass
class Edge:
    t: int  # ns
    level: bool  # level after the edge (True = contact closed / Z mark)
    truth: float | None = None  # exact position when the source knows it (Z mark)


@dataclass
class LatchResult:
    """One judged edge."""

    index: int  # k: paired with captured[k]
    t_ns: int
    true_counts: float
    uncertainty_counts: float
    captured: int | None
    error_counts: float | None  # captured - true
    status: str  # pass | fail | rejected (window / width) | skipped (edges: first)
    reason: str = ""
    width_counts: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def edges_from(source: Any, drive: str, line: int = 7, z: bool = False,
               since_ns: int | None = None) -> list[Edge]:
    """The capture input's edges in time order (see module doc)."""
    out: list[Edge] = []
    events = source.messages(topics.drive_events(drive))
    for t, m in events:
        if z and m.get("type") == "ZPulse":
            out.append(Edge(t, True, float(m["position_puu"])))
            out.append(Edge(t, False, float(m["position_puu"])))  # a mark has no width
        elif not z and m.get("type") == "InputChanged" and m.get("n") == line:
            out.append(Edge(t, bool(m["closed"])))
    if not out and not z:
        last = None
        for t, m in source.messages(topics.dio(drive, f"DI{line}")):
            lv = bool(m.get("level"))
            if last is not None and lv != last:
                out.append(Edge(t, lv))
            last = lv
    if since_ns is not None:
        out = [e for e in out if e.t >= since_ns]
    return out


class Reference:
    """Position samples (t, value) of the reference, interpolated linearly."""

    def __init__(self, samples: list[tuple[int, float]], resolution: float = 0.5) -> None:
        self.ts = [t for t, _ in samples]
        self.vs = [v for _, v in samples]
        self.resolution = resolution

    @classmethod
    def from_source(cls, source: Any, topic: str, field: str) -> Reference:
        got = []
        for t, m in source.messages(topic):
            v = m.get(field)
            if isinstance(v, int | float) and not isinstance(v, bool):
                got.append((t, float(v)))
        return cls(got)

    def at(self, t: int) -> tuple[float, float] | None:
        """(value, uncertainty) at t, None outside the samples."""
        ts, vs = self.ts, self.vs
        i = bisect.bisect_left(ts, t)
        if i < len(ts) and abs(ts[i] - t) <= 1000:  # a sample at the edge (1 µs)
            j = i
            while j + 1 < len(ts) and ts[j + 1] == ts[i]:
                j += 1  # several samples at one instant: the last is after the edge
            return vs[j], self.resolution
        if i == 0 or i >= len(ts):
            return None
        t0, t1, v0, v1 = ts[i - 1], ts[i], vs[i - 1], vs[i]
        v = v0 + (v1 - v0) * (t - t0) / (t1 - t0)
        return v, self.resolution + max(abs(v - v0), abs(v1 - v))


def judge(edges: list[Edge], reference: Reference, captured: list[int], *,
          trigger_level: bool = True, tolerance: float = 0.0,
          window: tuple[float, float] | None = None,
          width: tuple[float, float] | None = None, every: bool = True) -> list[LatchResult]:
    """Pair trigger edges with captured values and judge each accepted one."""
    out: list[LatchResult] = []
    triggers = [(i, e) for i, e in enumerate(edges) if e.level == trigger_level]
    accepted = 0
    for k, (i, e) in enumerate(triggers):
        got = reference.at(e.t) if e.truth is None else (e.truth, reference.resolution)
        if got is None:
            out.append(LatchResult(k, e.t, float("nan"), float("nan"), None, None,
                                   "inconclusive", "no reference sample around the edge"))
            continue
        true, unc = got
        cap = captured[k] if k < len(captured) else None
        # a drive's capture is a 32-bit register (P5.037, L11482): past ±2^31 it has wrapped
        # where the reference counts on
        res = LatchResult(k, e.t, true, unc, cap, None if cap is None else s32(cap - true),
                          "pass")
        if width is not None:
            nxt = next((x for x in edges[i + 1:] if x.level != trigger_level), None)
            end = None
            if nxt is not None:
                end = reference.at(nxt.t) if nxt.truth is None else (nxt.truth, 0.0)
            if end is None:
                res.status, res.reason = "rejected", "width: the pulse did not end (003:461)"
                out.append(res)
                continue
            res.width_counts = abs(end[0] - true)
            if not width[0] <= res.width_counts <= width[1]:
                res.status = "rejected"
                res.reason = (f"width {res.width_counts:.0f} outside {width[0]:g}..{width[1]:g}"
                              " (003:454)")
                out.append(res)
                continue
        if window is not None and not window[0] <= true <= window[1]:
            res.status = "rejected"
            res.reason = f"outside the window {window[0]:g}..{window[1]:g} (003:489)"
            out.append(res)
            continue
        accepted += 1
        if not every and accepted > 1:
            res.status, res.reason = "skipped", "edges: first"
            out.append(res)
            continue
        if cap is None:
            res.status, res.reason = "fail", "the drive captured no value for this edge"
        elif abs(res.error_counts) - unc > tolerance:
            res.status = "fail"
            res.reason = (f"error {res.error_counts:+.1f} ± {unc:.1f} counts beyond "
                          f"±{tolerance:g}")
        elif abs(res.error_counts) + unc > tolerance:
            res.status = "inconclusive"
            res.reason = f"error {res.error_counts:+.1f} ± {unc:.1f} straddles ±{tolerance:g}"
        out.append(res)
    return out


__all__ = ["Edge", "LatchResult", "Reference", "edges_from", "judge"]
