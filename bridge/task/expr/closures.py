"""The run-time form of a compiled expression: closures over a row of floats.

A compiled node is either a float (it folded to a constant) or a :data:`Code` closure that
reads its inputs from the row. Operations that can fail raise :class:`EvalError` naming the
sub-expression and its operand values, which :class:`bridge.task.expr.Expression` turns into a
:class:`~bridge.errors.BridgeError`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeAlias

Code = Callable[[list[float]], float]
# A compiled node: a float when it folded to a constant, a closure otherwise.
Compiled: TypeAlias = "float | Code"


class EvalError(Exception):
    """An operation failed while evaluating; carries the sub-expression and its operands."""

    def __init__(self, operation: str, exc: Exception) -> None:
        super().__init__(f"{operation} raised {type(exc).__name__}: {exc}")


def lift(compiled: Compiled) -> Code:
    """A closure for any compiled node; constants become closures that return them."""
    if isinstance(compiled, float):
        value = compiled

        def constant(row: list[float]) -> float:
            return value

        return constant
    return compiled


def safe_binop(op: Callable[[float, float], float], a: Compiled, b: Compiled) -> Code:
    """A binary operation that cannot raise, specialised for a constant on either side."""
    if isinstance(a, float):
        left, right = a, lift(b)

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


def risky_binop(op: Callable[[float, float], float], template: str, a: Compiled, b: Compiled) -> Code:
    """A binary operation that can raise; a failure names the operation and its operands."""
    fa, fb = lift(a), lift(b)

    def run(row: list[float]) -> float:
        x, y = fa(row), fb(row)
        try:
            return op(x, y)
        except (ArithmeticError, ValueError) as exc:
            raise EvalError(template.format(x, y), exc) from exc

    return run


def call_function(function: Callable[..., float], template: str, fs: list[Code]) -> Code:
    """Call a math function; a failure names the call and its argument values."""

    def fail(exc: Exception, *args: float) -> EvalError:
        return EvalError(template.format(", ".join(repr(a) for a in args)), exc)

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
