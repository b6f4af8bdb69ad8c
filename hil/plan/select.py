"""Choosing plans: `-k EXPR` on names, `-m EXPR` on tags, globs, as pytest users expect.

    matches("brake and not sto", {"servo_on_off_brake", "brake", "motion"})   # -k
    Expr.parse("brake or homing").match(tags, exact=True)                   # -m

An expression is words joined by `and`, `or`, `not` and parentheses. With `-k` a word
matches when it is a case-insensitive substring of the plan's name, its file's stem or one of
its tags; with `-m` it must equal a tag (globs like `fault_*` allowed).
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["KEYWORDS", "TAG_WORD", "Expr", "ExprError", "is_glob", "matches", "select"]

_TOKEN = re.compile(r"\s*(\(|\)|[^\s()]+)")
_WORD = re.compile(r"^[\w.*?\[\]:/-]+\Z")
TAG_WORD = re.compile(r"^[\w.:/-]+\Z")  # a plan's tag: a word without glob characters
KEYWORDS = ("and", "or", "not")
MAX_DEPTH = 100  # nested `not` / parentheses: an ExprError beyond, not a RecursionError


class ExprError(ValueError):
    """A malformed -k / -m expression (names the expression and the problem)."""


@dataclass(frozen=True)
class Expr:
    op: str  # "word", "not", "and", "or"
    args: tuple = ()
    word: str = ""

    @staticmethod
    def parse(text: str) -> Expr:
        tokens = _TOKEN.findall(text)
        if not tokens:
            raise ExprError(f"{text!r}: empty expression")
        pos = depth = 0

        def peek() -> str | None:
            return tokens[pos] if pos < len(tokens) else None

        def take() -> str:
            nonlocal pos
            pos += 1
            return tokens[pos - 1]

        def p_or() -> Expr:  # a chain is one n-ary node: `a or b or ...` never nests
            items = [p_and()]
            while peek() == "or":
                take()
                items.append(p_and())
            return items[0] if len(items) == 1 else Expr("or", tuple(items))

        def p_and() -> Expr:
            items = [p_not()]
            while peek() == "and":
                take()
                items.append(p_not())
            return items[0] if len(items) == 1 else Expr("and", tuple(items))

        def p_not() -> Expr:
            nonlocal depth
            tok = peek()
            if tok is None:
                raise ExprError(f"{text!r}: expression ends too early")
            if tok in ("not", "("):
                depth += 1
                if depth > MAX_DEPTH:
                    raise ExprError(f"{text[:40]!r}...: nested more than {MAX_DEPTH} deep")
                try:
                    return p_nested(tok)
                finally:
                    depth -= 1
            if tok in ("and", "or", ")") or not _WORD.match(tok):
                raise ExprError(f"{text!r}: unexpected {tok!r}")
            return Expr("word", word=take())

        def p_nested(tok: str) -> Expr:
            if tok == "not":
                take()
                return Expr("not", (p_not(),))
            take()
            inner = p_or()
            if peek() != ")":
                raise ExprError(f"{text!r}: missing ')'")
            take()
            return inner

        out = p_or()
        if pos != len(tokens):
            raise ExprError(f"{text!r}: unexpected {tokens[pos]!r}")
        return out

    def match(self, names: Iterable[str], *, exact: bool) -> bool:
        names = list(names)
        if self.op == "word":
            w = self.word.lower()
            if exact:
                return any(fnmatch.fnmatchcase(n.lower(), w) for n in names)
            return any(w in n.lower() for n in names)
        if self.op == "not":
            return not self.args[0].match(names, exact=exact)
        if self.op == "and":
            return all(a.match(names, exact=exact) for a in self.args)
        return any(a.match(names, exact=exact) for a in self.args)


def matches(expr: str, names: Iterable[str], *, exact: bool = False) -> bool:
    return Expr.parse(expr).match(names, exact=exact)


def is_glob(name: str) -> bool:
    return any(c in name for c in "*?[")


def select(plans: list, keyword: str | None = None, marker: str | None = None) -> list:
    """The plans (objects with `name`, `path`, `tags`) that `-k keyword` and `-m marker`
    both accept; raises ExprError for a malformed expression, an empty one (`-k ''`) included:
    it would select everything, which no one asks for by selecting."""
    k = Expr.parse(keyword) if keyword is not None else None
    m = Expr.parse(marker) if marker is not None else None
    out = []
    for p in plans:
        stem = p.path.rsplit("/", 1)[-1].removesuffix(".yaml") if p.path else p.name
        if k is not None and not k.match([p.name, stem, *p.tags], exact=False):
            continue
        if m is not None and not m.match(p.tags, exact=True):
            continue
        out.append(p)
    return out
