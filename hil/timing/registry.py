"""The timing specs a run can use: the shipped ones plus a plan directory's own, by id.

    specs = load_specs()              # fixtures/timing/*.yaml
    specs["brake_servo_off"]          # a Spec
    specs.broken                      # {file stem: why it did not load}

One broken spec file does not stop the plans that do not use it; a plan that names it is
refused with the reason (hil/plan/kinds/timing.py).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from hil.fileio import parsed_once
from hil.timing.spec import Spec, SpecError, load_spec, shipped_specs

__all__ = ["SpecRegistry", "load_specs"]


_ID_LINE = re.compile(r"^id:[ \t]*([\"']?)([A-Za-z0-9_.-]+)\1[ \t]*(?:#.*)?$", re.M)


class SpecRegistry(Mapping[str, Spec]):
    """Specs by id (a read-only mapping) and the files that failed to load (`broken`).

    Built from spec files, it parses a file when its spec is first asked for: a run of one
    plan reads the one or two specs it checks, not all of them (about 0.2 s a process). Each
    file's top-level `id:` line says which spec it holds; anything that does not fit that
    reading (no such line, a file that does not load, an id that differs once parsed) and
    listing the specs (`iter`, `len`, `broken`) load every file, as one eager pass would."""

    def __init__(self, specs: dict[str, Spec], broken: dict[str, str],
                 paths: list[Path] | None = None) -> None:
        self._specs = specs
        self._broken = broken
        self._paths = list(paths or [])
        self._index: dict[str, Path] = {}  # id -> the file its `id:` line names it in
        self._complete = not self._paths
        for p in self._paths:
            try:
                found = _ID_LINE.findall(Path(p).read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError):
                found = []
            if len(found) != 1:  # unreadable, or no single id line: read as one pass would
                self._load_all()
                return
            self._index[found[0][1]] = Path(p)

    def _load_all(self) -> None:
        if self._complete:
            return
        specs: dict[str, Spec] = {}
        broken: dict[str, str] = {}
        for p in self._paths:
            try:
                s = load_spec_cached(Path(p))
            except SpecError as e:
                broken[Path(p).stem] = str(e)
                continue
            specs[s.id] = s
        self._specs, self._broken, self._complete = specs, broken, True

    @property
    def broken(self) -> dict[str, str]:
        self._load_all()
        return self._broken

    def __getitem__(self, key: str) -> Spec:
        if self._complete:
            return self._specs[key]
        if key in self._specs:
            return self._specs[key]
        path = self._index.get(key)
        if path is None:
            raise KeyError(key)
        try:
            spec = load_spec_cached(path)
        except SpecError:
            spec = None
        if spec is None or spec.id != key:  # not as its id line said: one whole pass
            self._load_all()
            return self._specs[key]
        self._specs[key] = spec
        return spec

    def __iter__(self) -> Iterator[str]:
        self._load_all()
        return iter(self._specs)

    def __len__(self) -> int:
        self._load_all()
        return len(self._specs)

    def why_missing(self, spec_id: str) -> str:
        """Why `spec_id` cannot be used: its load error, or that no file defines it."""
        if spec_id in self.broken:
            return f"timing spec {spec_id!r} does not load: {self.broken[spec_id]}"
        return f"no timing spec {spec_id!r}; known: {', '.join(sorted(self._specs))}"


def load_specs(extra_dirs: Iterable[Path | str] | None = None) -> SpecRegistry:
    """The shipped specs plus every `*.yaml` in `extra_dirs` (a later file with the same id
    replaces an earlier one); each file is parsed when its spec is first used."""
    paths = list(shipped_specs())
    for d in extra_dirs or []:
        paths += sorted(Path(d).glob("*.yaml"))
    return SpecRegistry({}, {}, paths)


def load_spec_cached(path: Path) -> Spec:
    """`load_spec`, parsed once per file version in this process (`fileio.parsed_once`): each
    plan of a run asks for every spec."""
    return parsed_once("timing spec", path, lambda: load_spec(path))
