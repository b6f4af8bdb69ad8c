"""Files in and out, safely: inputs that are regular files read with a cap, outputs that are
never one of the inputs and are written atomically (a failed write leaves the old file).

A leaf: every command that reads a user's file or writes a result uses these, so a device
(`/dev/zero`), a directory or an output equal to an input gets the same clear error everywhere.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import stat
import tempfile
import unicodedata
from collections.abc import Callable, Hashable, Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


def _name_char(c: str) -> bool:
    """Kept in a file name: a letter, mark or digit of any script (`L*`, `M*`, `N*`: the
    vowel signs of Devanagari and the harakat of Arabic are marks), `_`, `.` and `-`; not a
    space, a separator, an anchor, a control or a format character (a bidi override)."""
    return c in "_.-" or unicodedata.category(c)[0] in "LMN"


def safe_stem(text: str, *, collapse: bool = False) -> str:
    """`text` as a file name: its letters, marks and digits kept in any script (NFC, so a
    name typed on one system and read on another is the same: `zkouška brzdy` stays
    `zkouška_brzdy`, `हिन्दी` stays whole), `.` and `-` kept, every other character `_`
    (`collapse`: every run of them one `_`). No separator or anchor is left."""
    out: list[str] = []
    for c in unicodedata.normalize("NFC", text):
        if _name_char(c):
            out.append(c)
        elif not (collapse and out and out[-1] == "_"):
            out.append("_")
    return "".join(out)


def fit_name(text: str, limit: int, key: str | None = None) -> str:
    """`text` if it fits in `limit` bytes, else cut to fit with `-` and 8 hex digits of a
    hash of `key` (default: `text` itself) after it: a long name stays a file name, and two
    long names that differ only past the cut stay apart. `key` given: always hashed."""
    if key is None and len(text.encode("utf-8")) <= limit:
        return text
    digest = hashlib.sha1((text if key is None else key).encode("utf-8")).hexdigest()[:8]
    return f"{fit_bytes(text, limit - 9)}-{digest}"


def fit_bytes(text: str, limit: int) -> str:
    """`text` cut to at most `limit` bytes of UTF-8, at a character boundary (a file name
    may hold 255 bytes, not characters)."""
    data = text.encode("utf-8")
    if len(data) <= limit:
        return text
    return data[:limit].decode("utf-8", "ignore")


class FileProblem(ValueError):
    """A file that cannot be used as given (the message names it and the reason)."""


def require_regular(path: str | os.PathLike, what: str = "file") -> os.stat_result:
    """`stat` of `path`, which must be a regular file (not a device, FIFO or directory).
    Raises `FileProblem`; a missing or unreadable file raises `OSError` as `open` would."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else
                "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else
                "a FIFO" if stat.S_ISFIFO(st.st_mode) else "not a regular file")
        raise FileProblem(f"{path}: {kind}, not a regular {what}")
    return st


def dir_problem(path: str | os.PathLike) -> str | None:
    """Why `path` cannot be an output directory (None: it is one, or can be made): a file
    where the directory belongs, or a file among its parents."""
    out = Path(path)
    if out.exists():
        if not out.is_dir():
            return "not a directory"
        return None if _writable(out) else "not writable"
    for parent in out.parents:
        if parent.exists():
            if not parent.is_dir():
                return f"{parent} is not a directory"
            return None if _writable(parent) else f"{parent} is not writable"
    return None


def _writable(directory: Path) -> bool:
    """A file can be made in `directory` (tried: permissions, a read-only mount, sysfs)."""
    try:
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".hil-write-test-"):
            return True
    except OSError:
        return False


def read_limited(path: str | os.PathLike, max_bytes: int | None, what: str = "file") -> bytes:
    """The bytes of regular file `path`, at most `max_bytes` (None: no cap) actually read:
    a file that grows while read (or lies about its size) cannot exhaust memory. Opened
    without blocking and checked on the open file, so a FIFO swapped in cannot hang it."""
    require_regular(path, what)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise FileProblem(f"{path}: not a regular {what}")
        if max_bytes is None:
            return f.read()
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise FileProblem(f"{path}: more than {max_bytes} bytes")
    return data


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when `a` and `b` name one file (through links, `..` or another spelling)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one does not exist (yet): compare the resolved paths
        return Path(a).resolve() == Path(b).resolve()


def refuse_input(out: str | os.PathLike, inputs: Iterable[str | os.PathLike],
                 flag: str) -> None:
    """Raise `FileProblem` when output `out` is one of `inputs`: a result never destroys
    what it was made from."""
    for src in inputs:
        if same_file(out, src):
            raise FileProblem(f"{flag} {out}: is the input {src}; choose another output file")


def _temp_for(path: Path) -> Path:
    # same directory (os.replace is atomic only within a file system), same suffix (writers
    # such as python-can's pick the format from it)
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it replaces `path` in one rename, on
    any error it is removed and `path` is left as it was. A symbolic link is written through
    (its target is replaced); a device or FIFO (`/dev/null`, `/dev/stdout`) is written in
    place, since renaming over it would replace the device node."""
    dest = Path(os.path.realpath(path))
    if dest.is_dir():
        raise IsADirectoryError(21, "is a directory", str(path))
    if dest.exists() and not dest.is_file():
        yield dest
        return
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_for(dest)
    try:
        yield tmp
        os.replace(tmp, dest)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_text_atomic(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write `text` to `path` atomically (temp file + rename); returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding=encoding)
    return Path(path)


_PARSED: dict[tuple, object] = {}


def parsed_once(kind: str, path: str | os.PathLike, parse: Callable[[], T],
                *key: Hashable) -> T:
    """`parse()` of the file at `path` as `kind`, done once per file version (path, mtime,
    size) and `key` in this process: a run parses the same EDS, tables and specs for
    every plan. What it returns is shared, so only for what nobody changes. A file that
    cannot be stat'ed is parsed every time (its own error is then `parse`'s)."""
    try:
        st = os.stat(path)
    except OSError:
        return parse()
    k = (kind, os.path.realpath(path), st.st_mtime_ns, st.st_size, *key)
    hit = _PARSED.get(k, _PARSED)
    if hit is _PARSED:
        hit = _PARSED[k] = parse()
    return hit  # type: ignore[return-value]


def _finite(obj: Any) -> Any:
    if isinstance(obj, float) and not math.isfinite(obj):
        return "NaN" if obj != obj else ("Infinity" if obj > 0 else "-Infinity")
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj


def dumps_strict(obj: Any, **kw: Any) -> str:
    """`json.dumps` that writes strict JSON (RFC 8259): a NaN or infinite number (a recorded
    parameter, say) becomes the text "NaN" / "Infinity" / "-Infinity" rather than a bare
    token other JSON readers refuse."""
    try:
        return json.dumps(obj, allow_nan=False, **kw)
    except ValueError:
        return json.dumps(_finite(obj), allow_nan=False, **kw)


__all__ = [
    "FileProblem",
    "atomic_path",
    "dumps_strict",
    "parsed_once",
    "read_limited",
    "refuse_input",
    "require_regular",
    "same_file",
    "write_text_atomic",
]
