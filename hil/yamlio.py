"""YAML with line numbers, for every file a person writes: plans, benches, timing specs.

`load_yaml_text(text, file, error=FileError)` returns plain dicts and lists that remember
where they were written (`LDict.line`, `LDict.kline(key)`, `LList.item_lines`), so a
validator can say `file:line: field: problem`. YAML syntax errors, duplicate keys and keys
that are not names raise `error` (a `FileError` subclass) with the same shape.

Hostile files are refused before they cost anything (limits, each with its own message and
line; raise them with the environment variables of the same name):
`HIL_YAML_MAX_BYTES` (1 MiB), `HIL_YAML_MAX_DEPTH` (64 nested collections),
`HIL_YAML_MAX_ALIASES` (100 `*alias` uses) and `HIL_YAML_MAX_NODES` (100 000 values after
aliases are expanded: an alias bomb stops here). Non-UTF-8 bytes and NUL bytes are refused
with the line they are on.
"""

from __future__ import annotations

import functools
import os
import re
from pathlib import Path
from typing import Any

import yaml

from hil.fileio import FileProblem, read_limited

MAX_PROBLEM = 400  # characters of an error's problem text


class FileError(ValueError):
    """A malformed file: `file:line: field: problem`."""

    def __init__(self, file: str, line: int, field: str, problem: str) -> None:
        if len(problem) > MAX_PROBLEM:  # a hostile value is named, not repeated in full
            problem = f"{problem[:MAX_PROBLEM - 60]}... ({len(problem)} characters in all)"
        if len(field) > 200:
            field = field[:160] + "..."
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
    """Field path: `steps[3].wait_until.timeout`. A key that is not printable on one line
    (a newline, a tab, an empty name) is shown quoted, so the message stays one line."""
    if isinstance(key, int):
        return f"{where}[{key}]"
    if not key.isprintable() or not key.strip():
        key = repr(key)
    return f"{where}.{key}" if where else key


def _key_text(key: Any, knode: yaml.Node) -> str:
    # a key is a name: keep its text as written. `P1.042:` parses as a string, but `on:` would
    # be a boolean in YAML 1.1 and `0x1017:` the integer 4119 (an SDO object 4119h)
    if not isinstance(key, str) and isinstance(knode, yaml.ScalarNode):
        return str(knode.value)
    return str(key)


def limit(name: str, default: int) -> int:
    """A size limit: the environment variable `name` if set to an integer, else `default`."""
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


# libyaml's loader when PyYAML has it (about 10x faster: the 40-odd timing specs a plan loads);
# any problem is parsed again by the pure-Python loader, so errors read the same either way
_FAST: type[yaml.SafeLoader] | None = getattr(yaml, "CSafeLoader", None)


def _shipped(file: str) -> bool:
    """A file the project ships (plans, specs, benches): the libyaml fast path is tested
    to read each the same as the Python loader. Other files are read by the Python loader
    only, as libyaml reads some broken text differently (a tab after a value, a bare `!`)."""
    try:
        p = Path(file).resolve()
    except (OSError, ValueError):
        return False
    return any(p.is_relative_to(d) for d in _shipped_roots())


@functools.cache
def _shipped_roots() -> tuple[Path, ...]:
    from hil.paths import fixtures_dir, plans_dir  # a leaf: imports nothing of hil

    return (fixtures_dir().resolve(), plans_dir().resolve())


def _prescan(text: str, file: str, error: type[FileError],
             loader: Any = yaml.SafeLoader) -> None:
    """Depth and alias limits on the event stream (PyYAML's parser does not recurse)."""
    max_depth = limit("HIL_YAML_MAX_DEPTH", 64)
    max_aliases = limit("HIL_YAML_MAX_ALIASES", 100)
    max_nodes = limit("HIL_YAML_MAX_NODES", 100_000)
    depth = aliases = nodes = 0
    for ev in yaml.parse(text, Loader=loader):
        if isinstance(ev, yaml.ScalarEvent | yaml.MappingStartEvent | yaml.SequenceStartEvent):
            nodes += 1  # as written, before any alias: refused here, before a node tree
            if nodes > max_nodes:  # of them is built (helper-139: 33 s and 378 MB to refuse
                raise error(file, ev.start_mark.line + 1, "(yaml)",  # a 520 000-value list)
                            f"more than {max_nodes} values (HIL_YAML_MAX_NODES)")
        if isinstance(ev, yaml.MappingStartEvent | yaml.SequenceStartEvent):
            depth += 1
            if depth > max_depth:
                raise error(file, ev.start_mark.line + 1, "(yaml)",
                            f"nested deeper than {max_depth} levels (HIL_YAML_MAX_DEPTH)")
        elif isinstance(ev, yaml.MappingEndEvent | yaml.SequenceEndEvent):
            depth -= 1
        elif isinstance(ev, yaml.AliasEvent):
            aliases += 1
            if aliases > max_aliases:
                raise error(file, ev.start_mark.line + 1, "(yaml)",
                            f"more than {max_aliases} aliases (HIL_YAML_MAX_ALIASES)")


class _Budget:
    """Values left to build: aliases re-use nodes, so an alias bomb would expand forever."""

    def __init__(self) -> None:
        self.max = limit("HIL_YAML_MAX_NODES", 100_000)
        self.left = self.max
        self.max_depth = limit("HIL_YAML_MAX_DEPTH", 64)


_MERGE_TAG = "tag:yaml.org,2002:merge"


def _build(node: yaml.Node, loader: yaml.SafeLoader, file: str, where: str,
           error: type[FileError], budget: _Budget | None = None,
           within: frozenset[int] = frozenset()) -> Any:
    line = node.start_mark.line + 1
    budget = budget or _Budget()
    budget.left -= 1
    if budget.left < 0:
        raise error(file, line, where or "(top)", f"more than {budget.max} values once aliases "
                    "are expanded (an alias bomb?; HIL_YAML_MAX_NODES)")
    if isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        if id(node) in within:  # `&x [*x]`: an alias inside its own anchor
            raise error(file, line, where or "(top)", "an alias inside its own anchor "
                        "(a value that contains itself)")
        within = within | {id(node)}
        if len(within) > budget.max_depth:  # aliases nest what the text does not
            raise error(file, line, where or "(top)", f"nested deeper than "
                        f"{budget.max_depth} levels once aliases are expanded "
                        "(HIL_YAML_MAX_DEPTH)")
    if isinstance(node, yaml.MappingNode):
        out = LDict()
        out.line, out.key_lines = line, {}
        for knode, vnode in node.value:
            kline = knode.start_mark.line + 1
            if knode.tag == _MERGE_TAG:  # `<<: *base`: each key must be on its own line
                raise error(file, kline, join(where, "<<"), "a YAML merge key is not supported "
                            "(a field's line must be its own): write the keys out")
            key = loader.construct_object(knode, deep=True)
            if not isinstance(key, str | int | float | bool):
                raise error(file, kline, where or "(top)", f"key {key!r} is not a name")
            key = _key_text(key, knode)
            if key in out:
                raise error(file, kline, join(where, key), "duplicate key")
            out.key_lines[key] = kline
            out[key] = _build(vnode, loader, file, join(where, key), error, budget, within)
        return out
    if isinstance(node, yaml.SequenceNode):
        lst = LList()
        lst.line, lst.item_lines = line, []
        for i, item in enumerate(node.value):
            lst.item_lines.append(item.start_mark.line + 1)
            lst.append(_build(item, loader, file, join(where, i), error, budget, within))
        return lst
    if (isinstance(node, yaml.ScalarNode) and not node.style
            and node.tag in (_INT_TAG, _FLOAT_TAG) and _YAML11_ONLY.match(node.value)):
        raise error(file, line, where or "(top)", f"{node.value!r}: YAML 1.1 reads this as an "
                    "octal or base-60 number (010 is 8, 1:40 is 100); write it in decimal, "
                    "0x.. for hex, or quote it for text")
    return loader.construct_object(node, deep=True)


_INT_TAG, _FLOAT_TAG = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
# the number forms YAML 1.1 has and readers expect decimal: a leading 0 (octal) and ':' (60)
_YAML11_ONLY = re.compile(r"^[-+]?(0[0-9_]+|[0-9][0-9_]*(:[0-5]?[0-9])+(\.[0-9_]*)?)\Z")


_ODD_NAMES = {"\u2028": "LINE SEPARATOR", "\u2029": "PARAGRAPH SEPARATOR",
              "\x85": "NEXT LINE"}
_ODD_BREAKS = re.compile("[\u2028\u2029\x85]")


def load_yaml_text(text: str, file: str, error: type[FileError] = FileError) -> Any:
    """Parse YAML keeping line numbers; problems raise `error(file, line, field, problem)`."""
    max_bytes = limit("HIL_YAML_MAX_BYTES", 1 << 20)
    if len(text) > max_bytes:
        raise error(file, 1, "(file)", f"{len(text)} characters, more than {max_bytes} "
                    "(HIL_YAML_MAX_BYTES)")
    if "\0" in text:
        raise error(file, text.count("\n", 0, text.index("\0")) + 1, "(file)",
                    "NUL byte: not a text file")
    odd = _ODD_BREAKS.search(text)
    if odd:  # YAML breaks a line there and editors do not: every later line would be off
        raise error(file, text.count("\n", 0, odd.start()) + 1, "(file)",
                    f"U+{ord(odd.group()):04X} ({_ODD_NAMES[odd.group()]}): YAML reads it as a "
                    "line break, most editors do not; remove it, or write it as an escape "
                    "in a double-quoted string")
    if _FAST is not None and _shipped(file):
        try:
            return _load(text, file, error, _FAST)
        except Exception:  # the Python loader below reports it precisely
            pass
    return _load(text, file, error, yaml.SafeLoader)


def _load(text: str, file: str, error: type[FileError], loader_cls: Any) -> Any:
    try:
        _prescan(text, file, error, loader_cls)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        raise error(file, (mark.line + 1) if mark else 1, "(yaml)", str(e.problem or e)) from None
    except yaml.YAMLError as e:  # reader errors: characters YAML does not allow
        pos = getattr(e, "position", 0) or 0
        raise error(file, text.count("\n", 0, pos) + 1, "(yaml)", str(e)) from None
    loader = loader_cls(text)
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
    max_bytes = limit("HIL_YAML_MAX_BYTES", 1 << 20)
    try:
        # the bytes actually read are capped: a device (/dev/zero) reports size 0
        data = read_limited(p, max_bytes, "YAML file")
    except FileProblem as e:
        why = str(e).removeprefix(f"{p}: ")
        if why.startswith("more than"):
            why += " (HIL_YAML_MAX_BYTES)"
        raise error(str(p), 1 if why.startswith("more than") else 0, "(file)", why) from None
    except OSError as e:
        raise error(str(p), 0, "(file)", f"cannot read: {e.strerror or e}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(str(p), data.count(b"\n", 0, e.start) + 1, "(file)",
                    f"not UTF-8 text: byte 0x{data[e.start]:02X} at offset {e.start}") from None
    return load_yaml_text(text, str(p), error)
