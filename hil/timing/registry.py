"""The timing specs a run can use: the shipped ones plus a plan directory's own, by id.

    specs = load_specs()              # fixtures/timing/*.yaml
    specs["brake_servo_off"]          # a Spec
    specs.broken                      # {file stem: why it did not load}

One broken spec file does not stop the plans that do not use it; a plan that names it is
refused with the reason (hil/plan/kinds/timing.py).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from hil.fileio import parsed_once
from hil.timing.spec import Spec, SpecError, load_spec, shipped_specs

__all__ = ["SpecRegistry", "load_specs"]


class SpecRegistry(Mapping[str, Spec]):
    """Specs by id (a read-only mapping) and the files that failed to load (`broken`)."""

    def __init__(self, specs: dict[str, Spec], broken: dict[str, str]) -> None:
        self._specs = specs
        self.broken = broken

    def __getitem__(self, key: str) -> Spec:
        return self._specs[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._specs)

    def __len__(self) -> int:
        return len(self._specs)

    def why_missing(self, spec_id: str) -> str:
        """Why `spec_id` cannot be used: its load error, or that no file defines it."""
        if spec_id in self.broken:
            return f"timing spec {spec_id!r} does not load: {self.broken[spec_id]}"
        return f"no timing spec {spec_id!r}; known: {', '.join(sorted(self._specs))}"


def load_specs(extra_dirs: Iterable[Path | str] | None = None) -> SpecRegistry:
    """The shipped specs plus every `*.yaml` in `extra_dirs` (a later file with the same id
    replaces an earlier one)."""
    paths = list(shipped_specs())
    for d in extra_dirs or []:
        paths += sorted(Path(d).glob("*.yaml"))
    specs: dict[str, Spec] = {}
    broken: dict[str, str] = {}
    for p in paths:
        try:
            s = load_spec_cached(Path(p))
        except SpecError as e:
            broken[p.stem] = str(e)
            continue
        specs[s.id] = s
    return SpecRegistry(specs, broken)


def load_spec_cached(path: Path) -> Spec:
    """`load_spec`, parsed once per file version in this process (`fileio.parsed_once`): each
    plan of a run asks for every spec."""
    return parsed_once("timing spec", path, lambda: load_spec(path))
