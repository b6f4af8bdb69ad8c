"""YAML with line numbers, for every file a person writes: plans, benches, timing specs.

`load_yaml_text(text, file, error=FileError)` returns plain dicts and lists that remember
where they were written (`LDict.line`, `LDict.kline(key)`, `LList.item_lines`), so a
validator can say `file:line: field: problem`. YAML syntax errors, duplicate keys and keys
that are not names raise `error` (a `FileError` subclass) with the same shape.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml


class FileError(ValueError):
    """A malformed file: `file:line: field: problem`."""

    def __init__(self, file: str, line: int, field: str, problem: str) -> None:
        self.file, self.line, self.field, self.problem = file, line, field, problem
        super().__init__(f"{file}:{line}: {field}: {problem}")


class LDict(dict):
    """A mapping that remembers its own line and each key's line (1-based)."""

    line: int = 0
    key_lines: dict[str, int]

    def kline(self, key: str) -> int:
        return self.key_lines.get(key, self.line)


class LList(list):
    """A sequence that remembers its own line and each item's line (1-based)."""

    line: int = 0
    item_lines: list[int]


def join(where: str, key: str | int) -> str:
    """Field path: `steps[3].wait_until.timeout`."""
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


def _key_text(key: Any, knode: yaml.Node) -> str:
    # `P1.042:` parses as a string; `on:`/`off:` would be booleans in YAML 1.1: keep the text
    if isinstance(key, bool) and isinstance(knode, yaml.ScalarNode):
        return str(knode.value)
    return str(key)


def _build(node: yaml.Node, loader: yaml.SafeLoader, file: str, where: str,
           error: type[FileError]) -> Any:
    line = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        out = LDict()
        out.line, out.key_lines = line, {}
        for knode, vnode in node.value:
            key = loader.construct_object(knode, deep=True)
            kline = knode.start_mark.line + 1
            if not isinstance(key, str | int | float | bool):
                raise error(file, kline, where or "(top)", f"key {key!r} is not a name")
            key = _key_text(key, knode)
            if key in out:
                raise error(file, kline, join(where, key), "duplicate key")
            out.key_lines[key] = kline
            out[key] = _build(vnode, loader, file, join(where, key), error)
        return out
    if isinstance(node, yaml.SequenceNode):
        lst = LList()
        lst.line, lst.item_lines = line, []
        for i, item in enumerate(node.value):
            lst.item_lines.append(item.start_mark.line + 1)
            lst.append(_build(item, loader, file, join(where, i), error))
        return lst
    return loader.construct_object(node, deep=True)


def load_yaml_text(text: str, file: str, error: type[FileError] = FileError) -> Any:
    """Parse YAML keeping line numbers; problems raise `error(file, line, field, problem)`."""
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise error(file, 1, "(top)", "empty file")
        return _build(node, loader, file, "", error)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line = (mark.line + 1) if mark else 1
        raise error(file, line, "(yaml)", str(e.problem or e)) from None
    finally:
        loader.dispose()


def load_yaml_file(path: str | Path, error: type[FileError] = FileError) -> Any:
    """`load_yaml_text` of a file; an unreadable file is an `error` at line 0."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise error(str(p), 0, "(file)", f"cannot read: {e.strerror or e}") from None
    return load_yaml_text(text, str(p), error)
