"""The tree-walking compiler: parses the text, resolves names and words every compile-time error.

:class:`Compiler` walks the syntax tree once; the per-node rules live in :mod:`bridge.task.expr.nodes`
and call back into the compiler for child nodes, name lookups, constant folding and messages.
Every message names the setting (``where``), the expression and the column, with a caret line.
"""

from __future__ import annotations

import ast
import difflib
import operator
from collections.abc import Callable, Sequence

from bridge.errors import ConfigError
from bridge.task.expr.closures import Code, Compiled
from bridge.task.expr.nodes import HANDLERS
from bridge.task.expr.tables import (
    ALLOWED,
    CONSTANTS,
    CONSTRUCTS,
    FUNCTIONS,
    MAX_DEPTH,
    MAX_LENGTH,
    SIGNATURES,
)


class Compiler:
    """Walks the syntax tree once, turning each node into a constant or a closure."""

    def __init__(self, text: str, names: Sequence[str], where: str) -> None:
        self.text = text
        self.where = where
        self.index: dict[str, int] = {}
        for i, name in enumerate(names):
            self.index.setdefault(name, i)
        self.used: dict[str, int] = {}
        self.display, self.source = one_line(text)
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
        functions = ", ".join(SIGNATURES.values())
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
        handler = HANDLERS.get(type(node))
        if handler is None:
            what = CONSTRUCTS.get(type(node), f"{type(node).__name__} expression")
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


def one_line(text: str) -> tuple[str, str]:
    """(``text`` on one line, the same without leading blanks: what is parsed). YAML block scalars
    bring newlines and indentation; one line keeps columns simple."""
    display = text.replace("\r", " ").replace("\n", " ")
    return display, display.lstrip()


def _depth(root: ast.AST) -> int:
    """Nesting depth of a tree, found without recursion."""
    deepest, stack = 0, [(root, 1)]
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    return deepest
