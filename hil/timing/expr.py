"""Small, safe expressions over drive parameters: `P1.042 + tol`, `max(P1.043, 0)`, `P1.038 / 10`.

Values are milliseconds (the manual's unit for P1.042, P1.043, P2.009). Numbers may carry a
unit (`20 ms`, `1 s`, `500 us`), converted to ms. Allowed: + - * /, unary -, min max abs,
`bit(P5.039, 0)` (bit n of a value), comparisons and and/or/not (for `when:`). Parameter
names are written as in the manual (`P1.042`); other names are spec constants or, in
`when:`, signal names.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Mapping
from typing import Any

PARAM_RE = re.compile(r"\bP(\d)\.(\d{3})\b")
_UNIT_RE = re.compile(r"(?<![\w.])(\d+(?:\.\d+)?)\s*(ms|us|s)\b")
_UNIT = {"ms": 1.0, "s": 1000.0, "us": 0.001}
_FUNCS = {"min": min, "max": max, "abs": abs,
          "bit": lambda v, n: (int(v) >> int(n)) & 1}  # bit(P5.039, 0): a parameter bit
_BINOPS = (ast.Add, ast.Sub, ast.Mult, ast.Div)
_CMPOPS = (ast.Eq, ast.NotEq, ast.Lt, ast.LtE, ast.Gt, ast.GtE)


class ExprError(ValueError):
    """An expression that does not parse or uses something not allowed."""


def is_param(name: str) -> bool:
    return PARAM_RE.fullmatch(name) is not None


def _to_python(text: str) -> str:
    out = PARAM_RE.sub(lambda m: f"P{m.group(1)}_{m.group(2)}", text)
    return _UNIT_RE.sub(lambda m: f"({float(m.group(1)) * _UNIT[m.group(2)]!r})", out)


def _display(pyname: str) -> str:
    m = re.fullmatch(r"P(\d)_(\d{3})", pyname)
    return f"P{m.group(1)}.{m.group(2)}" if m else pyname


class Expr:
    """A compiled expression; `names` are the parameter/constant/signal names it reads."""

    def __init__(self, text: str | int | float) -> None:
        self.text = str(text).strip()
        if not self.text:
            raise ExprError("empty expression")
        src = _to_python(self.text)
        try:
            tree = ast.parse(src, mode="eval")
        except SyntaxError as e:
            raise ExprError(f"cannot parse {self.text!r} ({e.msg})") from None
        pynames: set[str] = set()
        for node in ast.walk(tree):
            self._check(node, pynames)
        self.names = {_display(n) for n in pynames}
        self._pymap = {_display(n): n for n in pynames}
        self._code = compile(tree, "<expr>", "eval")

    def _check(self, node: ast.AST, pynames: set[str]) -> None:
        if isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id in _FUNCS):
                raise ExprError(f"{self.text!r}: only min, max, abs and bit may be called")
            if node.keywords or not node.args:
                raise ExprError(f"{self.text!r}: {node.func.id}() takes plain arguments")
            return
        if isinstance(node, ast.Name):
            if node.id not in _FUNCS:
                pynames.add(node.id)
            return
        if isinstance(node, ast.Constant):
            if not isinstance(node.value, int | float | str | bool):
                raise ExprError(f"{self.text!r}: constant {node.value!r} not allowed")
            return
        ok = (
            ast.Expression, ast.Load, ast.BinOp, ast.UnaryOp, ast.BoolOp, ast.Compare,
            ast.USub, ast.UAdd, ast.Not, ast.And, ast.Or, *_BINOPS, *_CMPOPS,
        )
        if not isinstance(node, ok):
            what = type(node).__name__
            raise ExprError(f"{self.text!r}: {what} not allowed (use + - * / min max abs)")

    @property
    def params(self) -> list[str]:
        return sorted(n for n in self.names if is_param(n))

    def eval(self, env: Mapping[str, Any]) -> Any:
        """Evaluate with `env` (display names -> values); KeyError names a missing name."""
        scope: dict[str, Any] = dict(_FUNCS)
        for disp, py in self._pymap.items():
            if disp not in env:
                raise KeyError(disp)
            scope[py] = env[disp]
        try:
            return eval(self._code, {"__builtins__": {}}, scope)
        except ZeroDivisionError:
            raise ExprError(f"{self.text!r}: division by zero") from None
        except TypeError as e:
            raise ExprError(f"{self.text!r}: {e}") from None

    def __repr__(self) -> str:
        return f"Expr({self.text!r})"

    def __str__(self) -> str:
        return self.text
