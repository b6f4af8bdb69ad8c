"""Small, safe expressions over drive parameters: `P1.042 + tol`, `max(P1.043, 0)`, `P1.038 / 10`.

Values are milliseconds (the manual's unit for P1.042, P1.043, P2.009). Numbers may carry a
unit (`20 ms`, `1 s`, `500 us`), converted to ms. Allowed: + - * /, unary -, min max abs,
`bit(P5.039, 0)` (bit n of a value), comparisons and and/or/not (for `when:`). Parameter
names are written as in the manual (`P1.042`); other names are spec constants or, in
`when:`, signal names.

Expressions are never handed to Python's `eval`: they are parsed with `ast` and walked by a
small interpreter that knows only the nodes above. Hostile text is refused with `ExprError`
naming the limit it broke (docs/timing.md, "Limits and refusals"):

- length limit: at most `MAX_CHARS` characters;
- depth limit: at most `MAX_DEPTH` nested operations; size limit: at most `MAX_NODES` parts;
- magnitude limit: every number (literal, name value, intermediate result) has
  |x| <= `MAX_MAGNITUDE` (2**64) and is finite (no NaN, no inf);
- no text arithmetic: text ('a') may only be compared (`mode == 'pp'`), never added,
  multiplied ('a' * 10**9) or negated;
- bit index limit: `bit(x, n)` needs an integer 0 <= n <= `MAX_BIT`.

`Expr.eval` raises only `ExprError` (a refused value or operation) or `KeyError` (a name the
environment does not give).
"""

from __future__ import annotations

import ast
import math
import re
from collections.abc import Callable, Mapping
from typing import Any

PARAM_RE = re.compile(r"\bP([0-9])\.([0-9]{3})\b")
_UNIT_RE = re.compile(r"(?<![\w.])([0-9]+(?:\.[0-9]+)?)\s*(ms|us|s)\b")
_UNIT = {"ms": 1.0, "s": 1000.0, "us": 0.001}
_FUNC_NAMES = ("min", "max", "abs", "bit")
_ARITY = {"min": (2, None), "max": (2, None), "abs": (1, 1), "bit": (2, 2)}

MAX_CHARS = 500  # length limit (characters of the expression text)
MAX_DEPTH = 32  # depth limit (nested operations)
MAX_NODES = 200  # size limit (parts: numbers, names, operators, calls)
MAX_MAGNITUDE = 2**64  # magnitude limit of every number
MAX_BIT = 63  # bit(x, n): 0 <= n <= MAX_BIT
_NOT_FINITE = {"nan", "inf", "infinity"}

_BINOPS: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: lambda a, b: a + b, ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b, ast.Div: lambda a, b: a / b,
}
_CMPOPS: dict[type, Callable[[Any, Any], bool]] = {
    ast.Eq: lambda a, b: a == b, ast.NotEq: lambda a, b: a != b,
    ast.Lt: lambda a, b: a < b, ast.LtE: lambda a, b: a <= b,
    ast.Gt: lambda a, b: a > b, ast.GtE: lambda a, b: a >= b,
}
_SYMBOL = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.USub: "-", ast.UAdd: "+"}


class ExprError(ValueError):
    """An expression that does not parse, uses something not allowed, breaks a limit, or
    whose value is refused (division by zero, not finite, beyond the magnitude limit)."""


def is_param(name: str) -> bool:
    return PARAM_RE.fullmatch(name) is not None


def _unit(m: re.Match) -> str:
    v = float(m.group(1)) * _UNIT[m.group(2)]
    return f"({v!r})" if math.isfinite(v) else "(1e999)"  # refused below as not finite


def _to_python(text: str) -> str:
    out = PARAM_RE.sub(lambda m: f"P{m.group(1)}_{m.group(2)}", text)
    return _UNIT_RE.sub(_unit, out)


def _display(pyname: str) -> str:
    m = re.fullmatch(r"P([0-9])_([0-9]{3})", pyname)
    return f"P{m.group(1)}.{m.group(2)}" if m else pyname


def _short(text: str, n: int = 60) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def check_number(v: Any, what: str) -> int | float:
    """`v` if it is a finite number within the magnitude limit, else ExprError naming `what`."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ExprError(f"{what} is not a number (got {_short(repr(v), 40)})")
    if isinstance(v, float) and not math.isfinite(v):
        raise ExprError(f"{what} is {v!r}: not a finite number")
    if abs(v) > MAX_MAGNITUDE:
        shown = f"{v:.3g}" if isinstance(v, float) else f"a {len(str(abs(v)))}-digit integer"
        raise ExprError(f"{what} is {shown}: beyond the magnitude limit (|x| <= 2**64)")
    return v


def _depth_and_size(tree: ast.AST) -> tuple[int, int]:
    """Nesting depth and node count, without recursion (the tree may be arbitrarily deep)."""
    deepest, count = 0, 0
    stack = [(tree, 1)]
    while stack:
        node, d = stack.pop()
        count += 1
        deepest = max(deepest, d)
        if deepest > MAX_DEPTH or count > MAX_NODES:
            break
        stack.extend((c, d + 1) for c in ast.iter_child_nodes(node)
                     if not isinstance(c, ast.expr_context | ast.operator | ast.unaryop
                                       | ast.cmpop | ast.boolop))
    return deepest, count


class Expr:
    """A compiled expression; `names` are the parameter/constant/signal names it reads;
    `kind` is what it yields, as far as can be told without values: "number", "bool",
    "text" or "any" (a lone name, an and/or of non-booleans)."""

    def __init__(self, text: str | int | float) -> None:
        if isinstance(text, float) and not math.isfinite(text):
            raise ExprError(f"{text!r} is not a finite number")
        self.text = str(text).strip()
        if not self.text:
            raise ExprError("empty expression")
        if len(self.text) > MAX_CHARS:
            raise ExprError(f"{_short(self.text, 40)!r}: too long, {len(self.text)} characters "
                            f"(length limit {MAX_CHARS})")
        src = _to_python(self.text)
        try:
            tree = ast.parse(src, mode="eval")
        except SyntaxError as e:
            raise ExprError(f"cannot parse {_short(self.text)!r} ({e.msg})") from None
        except (ValueError, RecursionError, MemoryError) as e:  # NUL bytes, parser depth
            why = "nested too deeply" if isinstance(e, RecursionError | MemoryError) else str(e)
            raise ExprError(f"cannot parse {_short(self.text)!r} ({why})") from None
        depth, size = _depth_and_size(tree)
        if depth > MAX_DEPTH:
            raise ExprError(f"{_short(self.text)!r}: nested too deeply (depth limit {MAX_DEPTH})")
        if size > MAX_NODES:
            raise ExprError(f"{_short(self.text)!r}: too many parts (size limit {MAX_NODES})")
        pynames: set[str] = set()
        self._pymap: dict[str, str] = {}
        self._callees: set[int] = set()  # the Name nodes that are the called function
        for node in ast.walk(tree):  # breadth first: a call is seen before its function name
            self._check(node, pynames)
        self._tree = tree.body
        self.names = {_display(n) for n in pynames}
        self._pymap = {n: _display(n) for n in pynames}
        self.kind = self._kind(self._tree)

    def _err(self, what: str) -> ExprError:
        return ExprError(f"{_short(self.text)!r}: {what}")

    def _check(self, node: ast.AST, pynames: set[str]) -> None:
        if isinstance(node, ast.Call):
            if not (isinstance(node.func, ast.Name) and node.func.id in _FUNC_NAMES):
                what = f"{node.func.id}()" if isinstance(node.func, ast.Name) else "that call"
                raise self._err(f"{what} not allowed: only min, max, abs and bit may be called")
            name = node.func.id
            self._callees.add(id(node.func))
            if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
                raise self._err(f"{name}() takes plain arguments")
            lo, hi = _ARITY[name]
            if len(node.args) < lo or (hi is not None and len(node.args) > hi):
                want = f"{lo}" if lo == hi else f"{lo} or more"
                raise self._err(f"{name}() takes {want} arguments, got {len(node.args)}")
            for a in node.args:
                if self._kind(a) == "text":
                    raise self._err(f"{name}() of text (no text arithmetic)")
            if name == "bit" and not any(isinstance(n, ast.Name) for n in ast.walk(node.args[1])):
                try:  # a literal bit index is checked now
                    self._bit_index(self._eval(node.args[1], {}))
                except ExprError as e:
                    raise self._err(str(e)) from None
            return
        if isinstance(node, ast.Name):
            if id(node) in self._callees:
                return
            if node.id.lower() in _NOT_FINITE:
                raise self._err(f"{node.id} is not a finite number")
            if node.id.startswith("__"):
                raise self._err(f"name {node.id!r} not allowed")
            if node.id in _FUNC_NAMES:
                raise self._err(f"{node.id} is a function: call it, {node.id}(...)")
            pynames.add(node.id)
            return
        if isinstance(node, ast.Constant):
            v = node.value
            if isinstance(v, bool | str):
                return
            if not _is_number(v):
                raise self._err(f"constant {_short(repr(v), 40)} not allowed")
            try:
                check_number(v, "number")
            except ExprError as e:
                raise self._err(str(e)) from None
            return
        if isinstance(node, ast.BinOp | ast.UnaryOp) and not isinstance(node.op, ast.Not):
            operands = [node.left, node.right] if isinstance(node, ast.BinOp) else [node.operand]
            if type(node.op) not in _SYMBOL:
                raise self._err(f"{type(node.op).__name__} not allowed (use + - * / min max abs)")
            if any(self._kind(o) == "text" for o in operands):
                raise self._err(f"text with {_SYMBOL[type(node.op)]} (no text arithmetic: "
                                "text may only be compared)")
            return
        ok = (
            ast.Expression, ast.Load, ast.UnaryOp, ast.BoolOp, ast.Compare,
            ast.Not, ast.And, ast.Or, *_BINOPS, *_CMPOPS, ast.USub, ast.UAdd,
        )
        if not isinstance(node, ok):
            what = type(node).__name__
            raise self._err(f"{what} not allowed (use + - * / min max abs)")

    def _kind(self, node: ast.AST) -> str:
        if isinstance(node, ast.Constant):
            v = node.value
            return "bool" if isinstance(v, bool) else "text" if isinstance(v, str) else "number"
        if isinstance(node, ast.Name):
            return "number" if is_param(_display(node.id)) else "any"
        if isinstance(node, ast.Compare) or (isinstance(node, ast.UnaryOp)
                                             and isinstance(node.op, ast.Not)):
            return "bool"
        if isinstance(node, ast.BoolOp):
            kinds = {self._kind(v) for v in node.values}
            return kinds.pop() if len(kinds) == 1 else "any"
        return "number"  # arithmetic, unary +/-, min max abs bit

    @property
    def params(self) -> list[str]:
        return sorted(n for n in self.names if is_param(n))

    def eval(self, env: Mapping[str, Any]) -> Any:
        """Evaluate with `env` (display names -> values); KeyError names a missing name, any
        refused value or operation is an ExprError."""
        try:
            return self._eval(self._tree, env)
        except ExprError as e:
            raise self._err(str(e)) from None

    def number(self, env: Mapping[str, Any]) -> int | float:
        """`eval`, and the value must be a finite number within the magnitude limit."""
        v = self.eval(env)
        try:
            return check_number(v, "the value")
        except ExprError as e:
            raise self._err(str(e)) from None

    def _eval(self, node: ast.AST, env: Mapping[str, Any]) -> Any:
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            name = self._pymap.get(node.id, _display(node.id))
            v = env[name]
            if _is_number(v):
                check_number(v, name)
            return v
        if isinstance(node, ast.BinOp):
            a, b = self._eval(node.left, env), self._eval(node.right, env)
            sym = _SYMBOL[type(node.op)]
            self._operand(a, sym)
            self._operand(b, sym)
            try:
                r = _BINOPS[type(node.op)](a, b)
            except ZeroDivisionError:
                raise ExprError("division by zero") from None
            except OverflowError:
                raise ExprError("result beyond the magnitude limit (|x| <= 2**64)") from None
            return check_number(r, "the result")
        if isinstance(node, ast.UnaryOp):
            v = self._eval(node.operand, env)
            if isinstance(node.op, ast.Not):
                return not v
            self._operand(v, _SYMBOL[type(node.op)])
            return -v if isinstance(node.op, ast.USub) else +v
        if isinstance(node, ast.BoolOp):
            v: Any = None
            for sub in node.values:
                v = self._eval(sub, env)
                if (isinstance(node.op, ast.And) and not v) or (isinstance(node.op, ast.Or)
                                                                and v):
                    return v
            return v
        if isinstance(node, ast.Compare):
            left = self._eval(node.left, env)
            for op, right_node in zip(node.ops, node.comparators, strict=True):
                right = self._eval(right_node, env)
                try:
                    ok = _CMPOPS[type(op)](left, right)
                except TypeError:
                    raise ExprError(f"cannot compare {_short(repr(left), 30)} with "
                                    f"{_short(repr(right), 30)}") from None
                if not ok:
                    return False
                left = right
            return True
        if isinstance(node, ast.Call):
            name = node.func.id  # type: ignore[attr-defined]
            args = [self._eval(a, env) for a in node.args]
            for a in args:
                self._operand(a, f"{name}()")
            if name == "min":
                return min(args)
            if name == "max":
                return max(args)
            if name == "abs":
                return abs(args[0])
            return (int(args[0]) >> self._bit_index(args[1])) & 1
        raise ExprError(f"{type(node).__name__} not allowed")  # refused by _check already

    @staticmethod
    def _operand(v: Any, op: str) -> None:
        if isinstance(v, str):
            raise ExprError(f"text {_short(repr(v), 30)} with {op} (no text arithmetic)")
        if not isinstance(v, int | float):  # bools are ints
            raise ExprError(f"{_short(repr(v), 30)} is not a number (with {op})")

    @staticmethod
    def _bit_index(n: Any) -> int:
        if (isinstance(n, bool) or not isinstance(n, int | float)
                or (isinstance(n, float) and not math.isfinite(n)) or not 0 <= n <= MAX_BIT
                or n != int(n)):
            raise ExprError(f"bit(x, n): n must be an integer 0..{MAX_BIT} (bit index limit), "
                            f"got {_short(repr(n), 30)}")
        return int(n)

    def __repr__(self) -> str:
        return f"Expr({self.text!r})"

    def __str__(self) -> str:
        return self.text
