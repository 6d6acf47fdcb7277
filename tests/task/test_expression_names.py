"""``expression_names``: every name an expression spells, unchecked, for resolving against a partial model."""

from __future__ import annotations

import pytest

from bridge.errors import ConfigError
from bridge.task.expr import MAX_LENGTH, compile_expression, expression_names

CASES = {
    "-(theta**2) - 0.1 * abs(x)": ("theta", "abs(x)", "abs", "x"),
    "load.omega - controller.reference": ("load.omega", "load", "controller.reference", "controller"),
    "-motor.y[2] + der(x) * pi": ("motor.y[2]", "motor.y", "motor", "der(x)", "der", "x", "pi"),
    "\n  a.b.c if cart.x > 0 else\n  0.0": ("a.b.c", "a.b", "a", "cart.x", "cart"),
}


@pytest.mark.parametrize("text", CASES)
def test_every_spelled_name_is_listed(text: str) -> None:
    assert set(expression_names(text)) == set(CASES[text])


@pytest.mark.parametrize("text", CASES)
def test_compiling_against_the_listed_names_resolves_every_name_used(text: str) -> None:
    """The reference is the compiler itself: what it reads is among the listed names."""
    names = expression_names(text)
    used = compile_expression(text, list(names)).names_used
    assert used and set(used) <= set(names)


@pytest.mark.parametrize("text", ["-(x", "x +* y", "", "x" * (MAX_LENGTH + 1)])
def test_text_that_does_not_compile_lists_nothing_and_the_compiler_says_why(text: str) -> None:
    assert expression_names(text) == ()
    with pytest.raises(ConfigError, match=r"reward\.expression"):
        compile_expression(text, ["x", "y"])
