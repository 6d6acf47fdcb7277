"""What an expression may use: limits, constants, math functions, operators, and names for the rest.

The compiler looks every syntax node up here; anything missing from these tables is rejected,
and :data:`CONSTRUCTS` gives the rejection a readable name.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable

MAX_LENGTH = 4000
# Compiling and evaluating recurse once per level; this stays far below Python's stack limit.
MAX_DEPTH = 200
CONSTANTS = {"pi": math.pi, "e": math.e}
ALLOWED = (
    "numbers, names, unary + and -, + - * / ** %, comparisons (< <= > >= == !=, chained; "
    "they give 1.0 or 0.0), and/or/not, 'a if cond else b' and calls of the functions listed next"
)


def _sign(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x  # 0.0, -0.0 or nan


def _clip(x: float, lo: float, hi: float) -> float:
    if lo > hi:
        raise ValueError(f"lower bound {lo!r} is above upper bound {hi!r}")
    return min(max(x, lo), hi)


def _floor(x: float) -> float:
    return float(math.floor(x))


def _ceil(x: float) -> float:
    return float(math.ceil(x))


# name -> (function, fewest arguments, most arguments or None for "no limit")
FUNCTIONS: dict[str, tuple[Callable[..., float], int, int | None]] = {
    "abs": (abs, 1, 1),
    "min": (min, 2, None),
    "max": (max, 2, None),
    "sqrt": (math.sqrt, 1, 1),
    "exp": (math.exp, 1, 1),
    "log": (math.log, 1, 1),
    "sin": (math.sin, 1, 1),
    "cos": (math.cos, 1, 1),
    "tan": (math.tan, 1, 1),
    "tanh": (math.tanh, 1, 1),
    "atan2": (math.atan2, 2, 2),
    "clip": (_clip, 3, 3),
    "sign": (_sign, 1, 1),
    "floor": (_floor, 1, 1),
    "ceil": (_ceil, 1, 1),
}
_SPECIAL = {
    "min": "min(a, b, ...)",
    "max": "max(a, b, ...)",
    "atan2": "atan2(y, x)",
    "clip": "clip(x, lo, hi)",
}
# How error messages show each function's arguments.
SIGNATURES = {name: _SPECIAL.get(name, f"{name}(x)") for name in FUNCTIONS}

SAFE_BINOPS: dict[type[ast.operator], Callable[[float, float], float]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
}
# Operations that can fail at run time; math.pow raises instead of returning a complex number.
RISKY_BINOPS: dict[type[ast.operator], tuple[str, Callable[[float, float], float]]] = {
    ast.Div: ("/", operator.truediv),
    ast.Mod: ("%", operator.mod),
    ast.Pow: ("**", math.pow),
}
COMPARE: dict[type[ast.cmpop], Callable[[float, float], bool]] = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
}
CONSTRUCTS: dict[type[ast.AST], str] = {
    ast.Attribute: "attribute access",
    ast.Subscript: "subscript",
    ast.Lambda: "lambda",
    ast.NamedExpr: "assignment expression (:=)",
    ast.Starred: "starred argument",
    ast.Tuple: "tuple",
    ast.List: "list",
    ast.Dict: "dict",
    ast.Set: "set",
    ast.ListComp: "list comprehension",
    ast.SetComp: "set comprehension",
    ast.DictComp: "dict comprehension",
    ast.GeneratorExp: "generator expression",
    ast.JoinedStr: "f-string",
    ast.Slice: "slice",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield from",
    ast.FloorDiv: "floor division (//)",
    ast.MatMult: "matrix multiplication (@)",
    ast.LShift: "shift (<<)",
    ast.RShift: "shift (>>)",
    ast.BitOr: "bitwise or (|)",
    ast.BitAnd: "bitwise and (&)",
    ast.BitXor: "bitwise xor (^)",
    ast.Invert: "bitwise not (~)",
    ast.In: "'in'",
    ast.NotIn: "'not in'",
    ast.Is: "'is'",
    ast.IsNot: "'is not'",
}
