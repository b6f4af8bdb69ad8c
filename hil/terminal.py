"""Text from a file (a spec, a recording) made safe where it is shown: a terminal gets no
escape sequence, an XML file or a page no character XML 1.0 forbids."""

from __future__ import annotations

import html
import re

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
# XML 1.0 allows tab, newline, carriage return and nothing else below 0x20; 0x7f-0x9f and
# the non-characters are discouraged, U+FFFE/U+FFFF forbidden
_NOT_XML = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ufffe\uffff]")
TEXT_MAX = 400  # characters of a file's own text (a name, a label) shown on a terminal


def terminal_text(text: object, limit: int = TEXT_MAX) -> str:
    """Control characters shown as \\xNN (an escape sequence would clear, retitle or spoof the
    terminal), and at most `limit` characters."""
    out = _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text))
    return out if len(out) <= limit else out[:limit] + f"... ({len(out)} characters)"


def xml_text(text: object) -> str:
    """The characters XML 1.0 cannot carry shown as \\xNN (a JUnit file stays well-formed)."""
    return _NOT_XML.sub(lambda m: f"\\x{ord(m.group()):02x}", str(text))


def html_text(text: object, quote: bool = True) -> str:
    """`html.escape` of `xml_text`: a page shows a control character as \\xNN too (a raw
    ESC from a plan name is no character HTML allows)."""
    return html.escape(xml_text(text), quote)


def terminal_lines(text: str) -> str:
    """`terminal_text` of each line of `text`, its newlines kept, no length limit."""
    return "\n".join(terminal_text(line, limit=1 << 62) for line in text.split("\n"))
