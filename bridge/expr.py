"""Safe arithmetic expressions for reward terms written in experiment files.

``compile_expression("-(theta**2) - 0.1 * abs(x)", ["x", "theta"])`` parses the text with
:mod:`ast` and turns the tree into nested Python closures; nothing the user writes is ever
handed to ``eval``, ``exec`` or ``compile``. Only numbers, the given names, the constants
``pi`` and ``e``, arithmetic, comparisons, ``and``/``or``/``not``, ``a if c else b`` and a
short list of math functions are accepted; everything else is a :class:`ConfigError` that
points at the offending column. All arithmetic is done on Python floats, so results equal
Python's own arithmetic on the same values.
"""

from __future__ import annotations

import ast
import difflib
import math
import operator
from collections.abc import Callable, Sequence
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError, ConfigError

Code = Callable[[list[float]], float]
# A compiled node: a float when it folded to a constant, a closure otherwise.
Compiled: TypeAlias = "float | Code"

MAX_LENGTH = 4000
# Compiling and evaluating recurse once per level; this stays far below Python's stack limit.
MAX_DEPTH = 200
CONSTANTS = {"pi": math.pi, "e": math.e}
ALLOWED = (
    "numbers, names, unary + and -, + - * / ** %, comparisons (< <= > >= == !=, chained; "
    "they give 1.0 or 0.0), and/or/not, 'a if cond else b' and calls of the functions listed next"
)


class _EvalError(Exception):
    """An operation failed while evaluating; carries the sub-expression and its operands."""

    def __init__(self, operation: str, exc: Exception) -> None:
        super().__init__(f"{operation} raised {type(exc).__name__}: {exc}")


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
_SAFE_BINOPS: dict[type[ast.operator], Callable[[float, float], float]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
}
# Operations that can fail at run time; math.pow raises instead of returning a complex number.
_RISKY_BINOPS: dict[type[ast.operator], tuple[str, Callable[[float, float], float]]] = {
    ast.Div: ("/", operator.truediv),
    ast.Mod: ("%", operator.mod),
    ast.Pow: ("**", math.pow),
}
_COMPARE: dict[type[ast.cmpop], Callable[[float, float], bool]] = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
}
_CONSTRUCTS: dict[type[ast.AST], str] = {
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


class Expression:
    """A compiled expression over a fixed list of names.

    Attributes:
        text: the expression as written.
        names_used: the names the expression reads, in order of first use.
    """

    __slots__ = ("_code", "_count", "_used", "_where", "names_used", "text")

    def __init__(self, text: str, used: dict[str, int], code: Code, count: int, where: str) -> None:
        self.text = text
        self.names_used = tuple(used)
        self._used = tuple(used.items())
        self._code = code
        self._count = count
        self._where = where

    def __call__(self, values: npt.NDArray[np.float64] | list[float]) -> float:
        """Evaluate with ``values[i]`` the value of ``names[i]`` (a list or a float array).

        Raises:
            BridgeError: an operation failed (``log(-1)``, division by zero, overflow) or the
                result is not finite; the message names the operation and the input values.
        """
        row: list[float] = values if isinstance(values, list) else values.tolist()
        if len(row) != self._count:
            raise BridgeError(
                f"{self._where}: {self.text!r} expects {self._count} values (one per name), "
                f"got {len(row)}; pass the vector the expression was compiled for"
            )
        try:
            result = self._code(row)
        except _EvalError as failure:
            raise self._error(row, str(failure)) from failure.__cause__
        if not math.isfinite(result):
            raise self._error(row, f"the result is {result!r}")
        return result

    def _error(self, row: list[float], reason: str) -> BridgeError:
        values = ", ".join(f"{name}={row[i]!r}" for name, i in self._used) or "(no names used)"
        return BridgeError(
            f"{self._where}: {self.text!r} failed: {reason}; values: {values}. "
            "Guard the operation in the expression (e.g. log(max(x, 1e-9)) or 'a if cond else b') "
            "or check why the inputs reach these values"
        )

    def __repr__(self) -> str:
        return f"Expression({self.text!r}, names_used={self.names_used!r})"


def compile_expression(text: str, names: Sequence[str], *, where: str = "reward.expression") -> Expression:
    """Compile ``text`` into an :class:`Expression` that reads ``values[i]`` as ``names[i]``.

    Dotted, indexed or ``der(...)`` names such as ``cart.x``, ``pos[1]`` or ``der(x)`` are
    accepted when the whole string is one of ``names``. Names shadow the constants ``pi``
    and ``e``. ``and``/``or`` follow Python (they return one of their operands).

    Raises:
        ConfigError: the text does not parse, uses a construct outside the allowed set,
            names an unknown variable, calls a function with the wrong number of arguments,
            or a constant part of it cannot be evaluated (such as ``1/0``).
    """
    compiler = _Compiler(text, names, where)
    code = _lift(compiler.compile())
    return Expression(text, compiler.used, code, len(names), where)


class _Compiler:
    """Walks the syntax tree once, turning each node into a constant or a closure."""

    def __init__(self, text: str, names: Sequence[str], where: str) -> None:
        self.text = text
        self.where = where
        self.index: dict[str, int] = {}
        for i, name in enumerate(names):
            self.index.setdefault(name, i)
        self.used: dict[str, int] = {}
        # YAML block scalars bring newlines and indentation; one line keeps columns simple.
        self.display = text.replace("\r", " ").replace("\n", " ")
        self.source = self.display.lstrip()
        self.lead = len(self.display) - len(self.source)
        self.source_bytes = self.source.encode("utf-8", "surrogatepass")

    def compile(self) -> Compiled:
        tree = self._parse()
        depth = _depth(tree.body)
        if depth > MAX_DEPTH:
            raise ConfigError(
                f"{self.where}: {self.text!r} is nested {depth} levels deep, more than the {MAX_DEPTH} "
                "allowed; split it into shorter terms"
            )
        return self.node(tree.body)

    def _parse(self) -> ast.Expression:
        if not self.source.strip():
            raise ConfigError(f"{self.where}: the expression is empty; write e.g. '-(theta**2)'")
        if len(self.source) > MAX_LENGTH:
            raise ConfigError(
                f"{self.where}: the expression has {len(self.source)} characters, more than the "
                f"{MAX_LENGTH} allowed; split it into shorter terms"
            )
        try:
            return ast.parse(self.source, mode="eval")
        except SyntaxError as exc:
            raise self._syntax_error(exc) from None
        except (ValueError, RecursionError, MemoryError) as exc:
            raise ConfigError(f"{self.where}: {self.text!r} cannot be parsed: {exc}") from None

    def _syntax_error(self, exc: SyntaxError) -> ConfigError:
        where = ""
        if exc.offset is not None:
            # Python reports offset 0 when the text ends too early.
            end = exc.offset <= 0 or exc.offset > len(self.source)
            column = len(self.display) + 1 if end else self.lead + exc.offset
            where = f" at {'the end' if end else f'column {column}'}\n{self.caret(column)}"
        return ConfigError(
            f"{self.where}: {self.text!r} is not a valid expression: {exc.msg}{where}\n"
            f"Expected an arithmetic expression such as '-(theta**2) - 0.1*abs(x)'"
        )

    def column(self, byte_offset: int) -> int:
        """1-based character column in ``text`` of a node's UTF-8 byte offset."""
        prefix = self.source_bytes[:byte_offset].decode("utf-8", "replace")
        return self.lead + len(prefix) + 1

    def caret(self, column: int) -> str:
        return f"  {self.display}\n  {' ' * (column - 1)}^"

    def segment(self, node: ast.expr) -> str:
        return ast.get_source_segment(self.source, node) or ast.unparse(node)

    def _available(self) -> str:
        names = list(self.index)
        shown = ", ".join(names[:40]) + (f", ... ({len(names) - 40} more)" if len(names) > 40 else "")
        functions = ", ".join(_SIGNATURES.values())
        return f"functions: {functions}; constants: pi, e; names: {shown or '(none)'}"

    def reject(self, what: str, byte_offset: int) -> ConfigError:
        column = self.column(byte_offset)
        return ConfigError(
            f"{self.where}: {what} at column {column} is not allowed in {self.text!r}\n"
            f"{self.caret(column)}\nAllowed: {ALLOWED}; {self._available()}"
        )

    def unknown(self, name: str, node: ast.expr, kind: str = "name") -> ConfigError:
        column = self.column(node.col_offset)
        pool = list(self.index) + list(CONSTANTS) + list(FUNCTIONS)
        close = difflib.get_close_matches(name, pool, n=3, cutoff=0.6)
        hint = f"did you mean {' or '.join(repr(c) for c in close)}? " if close else ""
        return ConfigError(
            f"{self.where}: unknown {kind} {name!r} at column {column} in {self.text!r}\n"
            f"{self.caret(column)}\n{hint}Available {self._available()}"
        )

    def fold(self, function: Callable[..., float], node: ast.expr, *args: float) -> float:
        """Evaluate a part whose inputs are all constants, now rather than at every call."""
        try:
            return float(function(*args))
        except (ArithmeticError, ValueError) as exc:
            raise ConfigError(
                f"{self.where}: the constant part {self.segment(node)!r} of {self.text!r} cannot be "
                f"evaluated: {type(exc).__name__}: {exc}; fix or remove it"
            ) from exc

    def node(self, node: ast.expr) -> Compiled:
        handler = _HANDLERS.get(type(node))
        if handler is None:
            what = _CONSTRUCTS.get(type(node), f"{type(node).__name__} expression")
            raise self.reject(what, node.col_offset)
        return handler(self, node)

    def operator_offset(self, left: ast.expr, right: ast.expr) -> int:
        """Byte offset of the operator between two operands (ast records only operand positions)."""
        start = left.end_col_offset or left.col_offset
        gap = self.source_bytes[start : right.col_offset]
        skip = len(gap) - len(gap.lstrip(b" \t)"))
        return start + skip

    def name(self, name: str, node: ast.expr) -> Compiled:
        if name in self.index:
            position = self.used.setdefault(name, self.index[name])
            getter: Code = operator.itemgetter(position)
            return getter
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name in FUNCTIONS:
            column = self.column(node.col_offset)
            raise ConfigError(
                f"{self.where}: {name!r} at column {column} is a function; call it, e.g. {name}(x), "
                f"in {self.text!r}\n{self.caret(column)}"
            )
        raise self.unknown(name, node)


def _lift(compiled: Compiled) -> Code:
    if isinstance(compiled, float):
        value = compiled

        def constant(row: list[float]) -> float:
            return value

        return constant
    return compiled


def _depth(root: ast.AST) -> int:
    """Nesting depth of a tree, found without recursion."""
    deepest, stack = 0, [(root, 1)]
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    return deepest


def _constants(parts: list[Compiled]) -> list[float] | None:
    """The values of ``parts`` when every one folded to a constant."""
    values = [p for p in parts if isinstance(p, float)]
    return values if len(values) == len(parts) else None


def _dotted(node: ast.expr) -> str | None:
    """The FMU-style variable name a node spells (``a.b``, ``v[1]``, ``der(x)``), if any."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return None if base is None else f"{base}.{node.attr}"
    if isinstance(node, ast.Subscript):
        base = _dotted(node.value)
        items = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        indices = [str(i.value) for i in items if isinstance(i, ast.Constant) and type(i.value) is int]
        if base is None or len(indices) != len(items):
            return None
        return f"{base}[{','.join(indices)}]"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) == 1:
        inner = _dotted(node.args[0])
        return None if inner is None or node.keywords else f"{node.func.id}({inner})"
    return None


def _constant(c: _Compiler, node: ast.Constant) -> Compiled:
    value = node.value
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:
            raise c.reject("a number too large for a float", node.col_offset) from None
    what = {str: "string literal", bytes: "bytes literal", bool: "boolean literal (write 1 or 0)"}.get(
        type(value), f"{type(value).__name__} literal"
    )
    raise c.reject(what, node.col_offset)


def _name(c: _Compiler, node: ast.Name) -> Compiled:
    return c.name(node.id, node)


def _path(c: _Compiler, node: ast.Attribute | ast.Subscript) -> Compiled:
    dotted = _dotted(node)
    if dotted is None:
        offset = node.value.end_col_offset or node.col_offset
        raise c.reject(_CONSTRUCTS[type(node)], offset)
    if dotted not in c.index:
        raise c.unknown(dotted, node)
    return c.name(dotted, node)


def _unary(c: _Compiler, node: ast.UnaryOp) -> Compiled:
    if isinstance(node.op, ast.Invert):
        raise c.reject(_CONSTRUCTS[ast.Invert], node.col_offset)
    operand = c.node(node.operand)
    if isinstance(node.op, ast.UAdd):
        return operand
    if isinstance(operand, float):
        return -operand if isinstance(node.op, ast.USub) else float(not operand)
    f = operand
    if isinstance(node.op, ast.USub):

        def negate(row: list[float]) -> float:
            return -f(row)

        return negate

    def invert(row: list[float]) -> float:
        return 0.0 if f(row) else 1.0

    return invert


def _binop(c: _Compiler, node: ast.BinOp) -> Compiled:
    kind = type(node.op)
    if kind not in _SAFE_BINOPS and kind not in _RISKY_BINOPS:
        what = _CONSTRUCTS.get(kind, kind.__name__)
        raise c.reject(what, c.operator_offset(node.left, node.right))
    a, b = c.node(node.left), c.node(node.right)
    if kind in _SAFE_BINOPS:
        op = _SAFE_BINOPS[kind]
        return c.fold(op, node, a, b) if isinstance(a, float) and isinstance(b, float) else _safe(op, a, b)
    symbol, risky = _RISKY_BINOPS[kind]
    if isinstance(a, float) and isinstance(b, float):
        return c.fold(risky, node, a, b)
    return _risky(risky, f"{c.segment(node)} = {{!r}} {symbol} {{!r}}", a, b)


def _safe(op: Callable[[float, float], float], a: Compiled, b: Compiled) -> Code:
    if isinstance(a, float):
        left, right = a, _lift(b)

        def const_left(row: list[float]) -> float:
            return op(left, right(row))

        return const_left
    fa = a
    if isinstance(b, float):
        value = b

        def const_right(row: list[float]) -> float:
            return op(fa(row), value)

        return const_right
    fb = b

    def both(row: list[float]) -> float:
        return op(fa(row), fb(row))

    return both


def _risky(op: Callable[[float, float], float], template: str, a: Compiled, b: Compiled) -> Code:
    """A binary operation that can raise; a failure names the operation and its operands."""
    fa, fb = _lift(a), _lift(b)

    def run(row: list[float]) -> float:
        x, y = fa(row), fb(row)
        try:
            return op(x, y)
        except (ArithmeticError, ValueError) as exc:
            raise _EvalError(template.format(x, y), exc) from exc

    return run


def _boolop(c: _Compiler, node: ast.BoolOp) -> Compiled:
    parts = [c.node(value) for value in node.values]
    is_and = isinstance(node.op, ast.And)
    if all(isinstance(p, float) for p in parts):
        for part in parts[:-1]:
            if bool(part) != is_and:
                return part
        return parts[-1]
    head = tuple(_lift(p) for p in parts[:-1])
    last = _lift(parts[-1])

    def run(row: list[float]) -> float:
        # Python's own semantics: the first operand that decides, else the last one.
        for f in head:
            value = f(row)
            if bool(value) != is_and:
                return value
        return last(row)

    return run


def _compare(c: _Compiler, node: ast.Compare) -> Compiled:
    left = node.left
    for cmpop, right in zip(node.ops, node.comparators, strict=True):
        if type(cmpop) not in _COMPARE:
            what = _CONSTRUCTS.get(type(cmpop), type(cmpop).__name__)
            raise c.reject(what, c.operator_offset(left, right))
        left = right
    parts = [c.node(node.left)] + [c.node(x) for x in node.comparators]
    ops = tuple(_COMPARE[type(op)] for op in node.ops)
    values = _constants(parts)
    if values is not None:
        return float(all(op(x, y) for op, x, y in zip(ops, values, values[1:], strict=False)))
    fs = [_lift(p) for p in parts]
    if len(ops) == 1:
        op, fa, fb = ops[0], fs[0], fs[1]

        def single(row: list[float]) -> float:
            return 1.0 if op(fa(row), fb(row)) else 0.0

        return single
    first, rest = fs[0], tuple(zip(ops, fs[1:], strict=True))

    def chained(row: list[float]) -> float:
        x = first(row)
        for op, f in rest:
            y = f(row)
            if not op(x, y):
                return 0.0
            x = y
        return 1.0

    return chained


def _ifexp(c: _Compiler, node: ast.IfExp) -> Compiled:
    test, body, orelse = c.node(node.test), c.node(node.body), c.node(node.orelse)
    if isinstance(test, float):
        return body if test else orelse
    ft, fb, fo = test, _lift(body), _lift(orelse)

    def run(row: list[float]) -> float:
        return fb(row) if ft(row) else fo(row)

    return run


def _call(c: _Compiler, node: ast.Call) -> Compiled:
    dotted = _dotted(node)
    if dotted is not None and dotted in c.index:
        return c.name(dotted, node)
    name = _function_name(c, node)
    if node.keywords:
        keyword = node.keywords[0]
        what = f"keyword argument '{keyword.arg}='" if keyword.arg else "keyword unpacking (**)"
        raise c.reject(what, keyword.col_offset)
    args = [c.node(arg) for arg in node.args]
    function, fewest, most = FUNCTIONS[name]
    if len(args) < fewest or (most is not None and len(args) > most):
        expected = f"{fewest} or more" if most is None else str(fewest)
        column = c.column(node.col_offset)
        raise ConfigError(
            f"{c.where}: {name}() takes {expected} arguments, got {len(args)}, at column {column} in "
            f"{c.text!r}\n{c.caret(column)}\nExpected: {_SIGNATURES[name]}"
        )
    values = _constants(args)
    if values is not None:
        return c.fold(function, node, *values)
    return _apply(function, f"{c.segment(node)} = {name}({{}})", [_lift(a) for a in args])


def _function_name(c: _Compiler, node: ast.Call) -> str:
    func = node.func
    if not isinstance(func, ast.Name):
        c.node(func)  # rejects attributes, lambdas, subscripts ... with their own message
        raise c.reject("a call of something other than a function name", node.col_offset)
    if func.id in FUNCTIONS:
        return func.id
    if func.id in c.index or func.id in CONSTANTS:
        raise c.reject(f"a call of {func.id!r} (a value, not a function)", node.col_offset)
    raise c.unknown(func.id, func, kind="function")


def _apply(function: Callable[..., float], template: str, fs: list[Code]) -> Code:
    """Call a math function; a failure names the call and its argument values."""

    def fail(exc: Exception, *args: float) -> _EvalError:
        return _EvalError(template.format(", ".join(repr(a) for a in args)), exc)

    if len(fs) == 1:
        f = fs[0]

        def one(row: list[float]) -> float:
            x = f(row)
            try:
                return function(x)
            except (ArithmeticError, ValueError) as exc:
                raise fail(exc, x) from exc

        return one

    def many(row: list[float]) -> float:
        args = [f(row) for f in fs]
        try:
            return function(*args)
        except (ArithmeticError, ValueError) as exc:
            raise fail(exc, *args) from exc

    return many


_SPECIAL = {
    "min": "min(a, b, ...)",
    "max": "max(a, b, ...)",
    "atan2": "atan2(y, x)",
    "clip": "clip(x, lo, hi)",
}
_SIGNATURES = {name: _SPECIAL.get(name, f"{name}(x)") for name in FUNCTIONS}

_HANDLERS: dict[type[ast.AST], Callable[[_Compiler, Any], Compiled]] = {
    ast.Constant: _constant,
    ast.Name: _name,
    ast.Attribute: _path,
    ast.Subscript: _path,
    ast.UnaryOp: _unary,
    ast.BinOp: _binop,
    ast.BoolOp: _boolop,
    ast.Compare: _compare,
    ast.IfExp: _ifexp,
    ast.Call: _call,
}
