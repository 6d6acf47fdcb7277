"""One compile rule per kind of syntax node: constants fold now, everything else becomes a closure.

Each handler receives the :class:`~bridge.task.expr.compiler.Compiler` (for child nodes, names and
messages) and one node, and returns a float or a :data:`~bridge.task.expr.closures.Code` closure.
:data:`HANDLERS` lists the node types an expression may contain; any other is rejected.
"""

from __future__ import annotations

import ast
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from bridge.errors import ConfigError
from bridge.task.expr.closures import Compiled, call_function, lift, risky_binop, safe_binop
from bridge.task.expr.tables import (
    COMPARE,
    CONSTANTS,
    CONSTRUCTS,
    FUNCTIONS,
    RISKY_BINOPS,
    SAFE_BINOPS,
    SIGNATURES,
)

if TYPE_CHECKING:
    from bridge.task.expr.compiler import Compiler


def _constants(parts: list[Compiled]) -> list[float] | None:
    """The values of ``parts`` when every one folded to a constant."""
    values = [p for p in parts if isinstance(p, float)]
    return values if len(values) == len(parts) else None


def dotted_name(node: ast.expr) -> str | None:
    """The FMU-style variable name a node spells (``a.b``, ``v[1]``, ``der(x)``), if any."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = dotted_name(node.value)
        return None if base is None else f"{base}.{node.attr}"
    if isinstance(node, ast.Subscript):
        base = dotted_name(node.value)
        items = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
        indices = [str(i.value) for i in items if isinstance(i, ast.Constant) and type(i.value) is int]
        if base is None or len(indices) != len(items):
            return None
        return f"{base}[{','.join(indices)}]"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) == 1:
        inner = dotted_name(node.args[0])
        return None if inner is None or node.keywords else f"{node.func.id}({inner})"
    return None


def _constant(c: Compiler, node: ast.Constant) -> Compiled:
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


def _name(c: Compiler, node: ast.Name) -> Compiled:
    return c.name(node.id, node)


def _path(c: Compiler, node: ast.Attribute | ast.Subscript) -> Compiled:
    dotted = dotted_name(node)
    if dotted is None:
        offset = node.value.end_col_offset or node.col_offset
        raise c.reject(CONSTRUCTS[type(node)], offset)
    if dotted not in c.index:
        raise c.unknown(dotted, node)
    return c.name(dotted, node)


def _unary(c: Compiler, node: ast.UnaryOp) -> Compiled:
    if isinstance(node.op, ast.Invert):
        raise c.reject(CONSTRUCTS[ast.Invert], node.col_offset)
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


def _binop(c: Compiler, node: ast.BinOp) -> Compiled:
    kind = type(node.op)
    if kind not in SAFE_BINOPS and kind not in RISKY_BINOPS:
        what = CONSTRUCTS.get(kind, kind.__name__)
        raise c.reject(what, c.operator_offset(node.left, node.right))
    a, b = c.node(node.left), c.node(node.right)
    if kind in SAFE_BINOPS:
        op = SAFE_BINOPS[kind]
        return (
            c.fold(op, node, a, b) if isinstance(a, float) and isinstance(b, float) else safe_binop(op, a, b)
        )
    symbol, risky = RISKY_BINOPS[kind]
    if isinstance(a, float) and isinstance(b, float):
        return c.fold(risky, node, a, b)
    return risky_binop(risky, f"{c.segment(node)} = {{!r}} {symbol} {{!r}}", a, b)


def _boolop(c: Compiler, node: ast.BoolOp) -> Compiled:
    parts = [c.node(value) for value in node.values]
    is_and = isinstance(node.op, ast.And)
    if all(isinstance(p, float) for p in parts):
        for part in parts[:-1]:
            if bool(part) != is_and:
                return part
        return parts[-1]
    head = tuple(lift(p) for p in parts[:-1])
    last = lift(parts[-1])

    def run(row: list[float]) -> float:
        # Python's own semantics: the first operand that decides, else the last one.
        for f in head:
            value = f(row)
            if bool(value) != is_and:
                return value
        return last(row)

    return run


def _compare(c: Compiler, node: ast.Compare) -> Compiled:
    left = node.left
    for cmpop, right in zip(node.ops, node.comparators, strict=True):
        if type(cmpop) not in COMPARE:
            what = CONSTRUCTS.get(type(cmpop), type(cmpop).__name__)
            raise c.reject(what, c.operator_offset(left, right))
        left = right
    parts = [c.node(node.left)] + [c.node(x) for x in node.comparators]
    ops = tuple(COMPARE[type(op)] for op in node.ops)
    values = _constants(parts)
    if values is not None:
        return float(all(op(x, y) for op, x, y in zip(ops, values, values[1:], strict=False)))
    fs = [lift(p) for p in parts]
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


def _ifexp(c: Compiler, node: ast.IfExp) -> Compiled:
    test, body, orelse = c.node(node.test), c.node(node.body), c.node(node.orelse)
    if isinstance(test, float):
        return body if test else orelse
    ft, fb, fo = test, lift(body), lift(orelse)

    def run(row: list[float]) -> float:
        return fb(row) if ft(row) else fo(row)

    return run


def _call(c: Compiler, node: ast.Call) -> Compiled:
    dotted = dotted_name(node)
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
            f"{c.text!r}\n{c.caret(column)}\nExpected: {SIGNATURES[name]}"
        )
    values = _constants(args)
    if values is not None:
        return c.fold(function, node, *values)
    return call_function(function, f"{c.segment(node)} = {name}({{}})", [lift(a) for a in args])


def _function_name(c: Compiler, node: ast.Call) -> str:
    func = node.func
    if not isinstance(func, ast.Name):
        c.node(func)  # rejects attributes, lambdas, subscripts ... with their own message
        raise c.reject("a call of something other than a function name", node.col_offset)
    if func.id in FUNCTIONS:
        return func.id
    if func.id in c.index or func.id in CONSTANTS:
        raise c.reject(f"a call of {func.id!r} (a value, not a function)", node.col_offset)
    raise c.unknown(func.id, func, kind="function")


HANDLERS: dict[type[ast.AST], Callable[[Compiler, Any], Compiled]] = {
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
