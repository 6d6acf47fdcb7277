"""Safe arithmetic expressions for reward terms written in experiment files.

``compile_expression("-(theta**2) - 0.1 * abs(x)", ["x", "theta"])`` parses the text with
:mod:`ast` and turns the tree into nested Python closures; nothing the user writes is ever
handed to ``eval``, ``exec`` or ``compile``. Only numbers, the given names, the constants
``pi`` and ``e``, arithmetic, comparisons, ``and``/``or``/``not``, ``a if c else b`` and a
short list of math functions are accepted; everything else is a :class:`ConfigError` that
points at the offending column. All arithmetic is done on Python floats, so results equal
Python's own arithmetic on the same values.

What is allowed lives in :mod:`~bridge.task.expr.tables`; :mod:`~bridge.task.expr.compiler` and
:mod:`~bridge.task.expr.nodes` walk the tree, and :mod:`~bridge.task.expr.closures` holds the run-time pieces.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from bridge.errors import BridgeError
from bridge.task.expr.closures import Code, EvalError, lift
from bridge.task.expr.compiler import Compiler, one_line
from bridge.task.expr.nodes import dotted_name
from bridge.task.expr.tables import ALLOWED, CONSTANTS, FUNCTIONS, MAX_DEPTH, MAX_LENGTH

__all__ = [
    "ALLOWED",
    "CONSTANTS",
    "FUNCTIONS",
    "MAX_DEPTH",
    "MAX_LENGTH",
    "Expression",
    "compile_expression",
    "expression_names",
]


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
        except EvalError as failure:
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
    compiler = Compiler(text, names, where)
    code = lift(compiler.compile())
    return Expression(text, compiler.used, code, len(names), where)


def expression_names(text: str) -> tuple[str, ...]:
    """Every variable name ``text`` spells (``x``, ``cart.x``, ``pos[1]``, ``der(x)``), in order
    and unchecked, with the parts of longer names (``cart.x[1]`` gives ``cart.x`` and ``cart``)
    and the names of functions called; ``()`` when the text does not parse
    (:func:`compile_expression` words that error).

    For resolving names against a partial model: a node serving one component of a system
    knows only that component's variables and takes the others' names as written."""
    source = one_line(text)[1]
    if len(source) > MAX_LENGTH:
        return ()
    try:
        tree = ast.parse(source, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError):
        return ()
    spelled = (dotted_name(node) for node in ast.walk(tree) if isinstance(node, ast.expr))
    return tuple(dict.fromkeys(name for name in spelled if name is not None))
