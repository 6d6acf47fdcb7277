"""Reward expressions: same results as Python, clear rejections, nothing but arithmetic can run."""

from __future__ import annotations

import ast
import builtins
import cmath
import math
import random
import re
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from bridge.errors import BridgeError, ConfigError
from bridge.task.expr import compile_expression

NAMES = ["x", "y", "theta", "omega"]
FUNCS_1 = ["abs", "sqrt", "exp", "log", "sin", "cos", "tan", "tanh", "sign", "floor", "ceil"]


def python_value(text: str, values: dict[str, float]) -> Any:
    """The reference: CPython evaluating the same text over the same floats (test-generated text only)."""
    namespace: dict[str, Any] = {
        "__builtins__": {},
        "abs": abs,
        "min": min,
        "max": max,
        "sqrt": math.sqrt,
        "exp": math.exp,
        "log": math.log,
        "sin": math.sin,
        "cos": math.cos,
        "tan": math.tan,
        "tanh": math.tanh,
        "atan2": math.atan2,
        "clip": lambda v, lo, hi: float(np.clip(v, lo, hi)),
        "sign": lambda v: float(np.sign(float(v))),
        "floor": math.floor,
        "ceil": math.ceil,
        "pi": math.pi,
        "e": math.e,
    }
    return eval(text, namespace, dict(values))


def random_expression(rng: random.Random, depth: int) -> str:
    if depth == 0 or rng.random() < 0.2:
        return rng.choice([*NAMES, "pi", "e", str(rng.randint(0, 9)), f"{rng.uniform(-5, 5):.3f}"])

    def sub() -> str:
        return random_expression(rng, depth - 1)

    def power() -> str:
        # A fractional power of a negative number is complex in Python; the exponent stays small.
        exponent = rng.choice(["2", "3", "-1", "0", "x", "0.5"])
        return f"(abs({sub()}) ** {exponent})" if exponent in ("x", "0.5") else f"({sub()} ** {exponent})"

    def comparison() -> str:
        ops = rng.choices(["<", "<=", ">", ">=", "==", "!="], k=rng.randint(1, 2))
        return "(" + sub() + "".join(f" {op} {sub()}" for op in ops) + ")"

    makers: list[Callable[[], str]] = [
        lambda: f"({sub()} {rng.choice(['+', '-', '*', '/', '%'])} {sub()})",
        power,
        lambda: f"({rng.choice(['-', '+', 'not '])}{sub()})",
        comparison,
        lambda: f"({sub()} {rng.choice(['and', 'or'])} {sub()})",
        lambda: f"({sub()} if {sub()} else {sub()})",
        lambda: f"{rng.choice(FUNCS_1)}({sub()})",
        lambda: f"{rng.choice(['min', 'max'])}({', '.join(sub() for _ in range(rng.randint(2, 3)))})",
        lambda: f"atan2({sub()}, {sub()})",
        lambda: f"clip({sub()}, -2, 3.5)",
    ]
    return rng.choice(makers)()


def assert_matches_python(text: str, row: np.ndarray) -> str:
    values = dict(zip(NAMES, row.tolist(), strict=True))
    try:
        expected = python_value(text, values)
        ok = isinstance(expected, (int, float)) and math.isfinite(expected)
    except (ArithmeticError, ValueError):
        ok = False
    try:
        expression = compile_expression(text, NAMES)
    except ConfigError as exc:
        # Only constant parts are evaluated while compiling; the failing part must fail in Python too.
        part = re.search(r"constant part '(.+?)' of", str(exc))
        assert part is not None, str(exc)
        with pytest.raises((ArithmeticError, ValueError)):
            python_value(part.group(1), {})
        return "constant"
    if ok:
        assert math.isclose(expression(row), float(expected), rel_tol=1e-9, abs_tol=1e-9), text
        return "value"
    with pytest.raises(BridgeError) as info:
        expression(row)
    assert not isinstance(info.value, ConfigError)
    return "error"


def test_random_expressions_equal_python_arithmetic() -> None:
    rng = random.Random(20240611)
    outcomes = {"value": 0, "error": 0, "constant": 0}
    for _ in range(3000):
        text = random_expression(rng, depth=4)
        row = np.array([rng.uniform(-3, 3) for _ in NAMES])
        if rng.random() < 0.1:
            row[rng.randrange(len(NAMES))] = 0.0
        outcomes[assert_matches_python(text, row)] += 1
    # The generator must exercise both successful and failing evaluations.
    assert outcomes["value"] > 1500
    assert outcomes["error"] > 50


@pytest.mark.parametrize(
    "text",
    [
        "-x ** 2",
        "2 ** -1",
        "2 ** 3 ** 2",
        "x - y - theta",
        "x / y / theta",
        "-7 % 3 + x % -2",
        "1 < x + 3 < 5",
        "x < y > theta",
        "not x < y",
        "x if y > 0 else theta if omega > 0 else -1",
        "x and y or theta",
        "0 and 1/x",
        "1 or log(-x)",
        "-(theta**2) - 0.1 * abs(x) - 0.01 * omega**2",
        "atan2(y, x) + clip(x * 10, -1, 1) + sign(-y) + floor(x) + ceil(y)",
        "min(x, y, theta, omega) * max(x, 1) + pi * e",
        "sqrt(abs(x)) + exp(-y) + log(1 + x * x) + sin(x) * cos(y) + tan(theta) + tanh(omega)",
        "12 + 0.5e1 + 1_000 + .25",
        "(x == x) + (x != y) + (x >= y) + (x <= y)",
    ],
)
def test_hand_written_expressions_equal_python_arithmetic(text: str) -> None:
    row = np.array([0.7, -1.3, 0.25, 2.0])
    assert assert_matches_python(text, row) == "value"


def test_names_used_are_listed_once_in_order_of_first_use() -> None:
    expression = compile_expression("theta * 2 + x - theta + pi", NAMES)
    assert expression.names_used == ("theta", "x")
    assert expression.text == "theta * 2 + x - theta + pi"


def test_values_are_read_by_position_in_names() -> None:
    expression = compile_expression("10 * omega + x", NAMES)
    assert expression(np.array([1.0, 50.0, 60.0, 2.0])) == 21.0


def test_variable_names_shadow_constants() -> None:
    assert compile_expression("e + pi", ["e"])(np.array([1.0])) == 1.0 + math.pi


def test_fmu_style_names_are_read_when_spelled_in_full() -> None:
    names = ["cart.x", "der(cart.x)", "pos[1]", "grid[2,3]"]
    expression = compile_expression("cart.x + der(cart.x) * 10 + pos[1] * 100 + grid[2, 3]", names)
    assert expression(np.array([1.0, 2.0, 3.0, 4.0])) == 325.0
    assert expression.names_used == tuple(names)


def test_multi_line_text_from_yaml_block_compiles() -> None:
    expression = compile_expression("  -(theta**2)\n  - 0.1 * abs(x)\n", NAMES)
    assert expression(np.array([1.0, 0.0, 2.0, 0.0])) == pytest.approx(-4.1)


def test_constant_expression_folds_and_still_evaluates() -> None:
    assert compile_expression("2 ** 10 / 4 - 1", NAMES)(np.zeros(4)) == 255.0


def rejection(text: str, names: list[str] = NAMES) -> str:
    with pytest.raises(ConfigError) as info:
        compile_expression(text, names, where="rewards.balance")
    message = str(info.value)
    assert message.startswith("rewards.balance: ")
    return message


@pytest.mark.parametrize(
    ("text", "construct", "column"),
    [
        ("x.real", "unknown name 'x.real'", 1),
        ("(x + 1).real", "attribute access", 7),
        ("(x, y)[0]", "subscript", 7),
        ("(lambda: 1)()", "lambda", 2),
        ("x + 'a'", "string literal", 5),
        ("x + b'a'", "bytes literal", 5),
        ("x + True", "boolean literal", 5),
        ("x + 1j", "complex literal", 5),
        ("x + None", "NoneType literal", 5),
        ("[x for x in y]", "list comprehension", 1),
        ("sum(v for v in y)", "unknown function 'sum'", 1),
        ("max(*y, 1)", "starred argument", 5),
        ("max(x, y, key=abs)", "keyword argument 'key='", 11),
        ("(z := 3) + x", "assignment expression (:=)", 2),
        ("x // 2", "floor division (//)", 3),
        ("x @ y", "matrix multiplication (@)", 3),
        ("x << 1", "shift (<<)", 3),
        ("x | y", "bitwise or (|)", 3),
        ("~x", "bitwise not (~)", 1),
        ("x in y", "'in'", 3),
        ("(x) is not y", "'is not'", 5),
        ("{x: y}", "dict", 1),
        ("f'{x}'", "f-string", 1),
        ("x(2)", "a call of 'x' (a value, not a function)", 1),
        ("(x + 1)(2)", "a call of something other than a function name", 1),
        ("x + 10**400", "constant part '10**400'", None),
        ("log(0) + x", "constant part 'log(0)'", None),
    ],
)
def test_rejected_construct_is_named_with_its_column(text: str, construct: str, column: int | None) -> None:
    message = rejection(text)
    assert construct in message
    if column is not None:
        assert f"column {column}" in message
        caret_line = message.splitlines()[2]
        assert caret_line.index("^") - 2 == column - 1


def test_rejection_lists_what_is_allowed() -> None:
    message = rejection("x // 2")
    assert "Allowed:" in message
    for item in ("+ - * / ** %", "and/or/not", "clip(x, lo, hi)", "atan2(y, x)", "pi, e", "theta, omega"):
        assert item in message


def test_unknown_name_suggests_close_matches_and_lists_names() -> None:
    message = rejection("thetta + x")
    assert "unknown name 'thetta'" in message
    assert "did you mean 'theta'" in message
    assert "names: x, y, theta, omega" in message


def test_unknown_function_suggests_close_matches() -> None:
    message = rejection("sqr(x)")
    assert "unknown function 'sqr'" in message
    assert "did you mean 'sqrt'" in message


def test_function_used_as_value_says_to_call_it() -> None:
    assert "is a function; call it, e.g. sin(x)" in rejection("sin + 1")


@pytest.mark.parametrize(
    ("text", "fragment"),
    [("min(x)", "min() takes 2 or more arguments, got 1"), ("clip(x, 1)", "clip() takes 3 arguments, got 2")],
)
def test_wrong_argument_count_shows_the_signature(text: str, fragment: str) -> None:
    message = rejection(text)
    assert fragment in message
    assert "Expected: " in message


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("x +* 2", "at column 4"),
        ("x + (y", "at column 5"),
        ("x + y +", "at the end"),
        ("é + (", "at column 5"),
    ],
)
def test_syntax_error_points_at_the_column(text: str, where: str) -> None:
    message = rejection(text)
    assert "is not a valid expression" in message
    assert where in message
    assert "^" in message


@pytest.mark.parametrize("text", ["", "   \n  "])
def test_empty_expression_is_rejected(text: str) -> None:
    assert "the expression is empty" in rejection(text)


def test_very_deep_nesting_is_rejected_before_compiling() -> None:
    assert "levels deep" in rejection("-" * 500 + "x")


@pytest.mark.parametrize(
    ("text", "values", "fragments"),
    [
        ("log(x - 1) + y", [0.5, 2.0, 0, 0], ["log(x - 1) = log(-0.5)", "math domain error", "x=0.5, y=2.0"]),
        ("y / x", [0.0, 3.0, 0, 0], ["y / x = 3.0 / 0.0", "ZeroDivisionError", "y=3.0, x=0.0"]),
        ("theta % x", [0.0, 0, 1.0, 0], ["theta % x = 1.0 % 0.0", "ZeroDivisionError"]),
        ("x ** 0.5", [-4.0, 0, 0, 0], ["x ** 0.5 = -4.0 ** 0.5", "math domain error"]),
        ("exp(x)", [1000.0, 0, 0, 0], ["exp(x) = exp(1000.0)", "OverflowError"]),
        ("sqrt(x)", [-1.0, 0, 0, 0], ["sqrt(x) = sqrt(-1.0)"]),
        ("clip(y, x, 0)", [1.0, 5.0, 0, 0], ["clip(y, x, 0) = clip(5.0, 1.0, 0.0)", "lower bound"]),
        ("x * 1e308 * 10", [1.0, 0, 0, 0], ["the result is inf", "x=1.0"]),
        ("x + y", [float("nan"), 1.0, 0, 0], ["the result is nan", "x=nan, y=1.0"]),
    ],
)
def test_math_failure_at_run_time_names_operation_and_values(
    text: str, values: list[float], fragments: list[str]
) -> None:
    expression = compile_expression(text, NAMES, where="rewards.balance")
    with pytest.raises(BridgeError) as info:
        expression(np.array(values))
    assert not isinstance(info.value, ConfigError)
    message = str(info.value)
    assert message.startswith(f"rewards.balance: {text!r} failed: ")
    for fragment in fragments:
        assert fragment in message


def test_wrong_number_of_values_is_an_error() -> None:
    expression = compile_expression("x", NAMES)
    with pytest.raises(BridgeError, match="expects 4 values"):
        expression(np.zeros(3))


ESCAPES = [
    "__import__('os').system('touch /tmp/pwned')",
    "().__class__.__bases__[0].__subclasses__()",
    "[c for c in ().__class__.__base__.__subclasses__()]",
    "open('/etc/passwd').read()",
    "eval('1')",
    "exec('import os')",
    "globals()",
    "getattr(x, '__class__')",
    "x.__class__",
    "(lambda: __import__('os'))()",
    "__builtins__",
    "breakpoint()",
    "f'{x.__class__}'",
    "type(x)('1')",
    "[].append(1)",
    "{}.__init__.__globals__",
    "(yield)",
]


@pytest.mark.parametrize("text", ESCAPES)
def test_nothing_but_arithmetic_can_run(text: str, monkeypatch: pytest.MonkeyPatch) -> None:
    real_compile = builtins.compile

    def syntax_tree_only(source: Any, filename: Any, mode: str, flags: int = 0, *args: Any, **kw: Any) -> Any:
        # ast.parse compiles to a tree only; asking for a code object would mean user text could run.
        assert flags & ast.PyCF_ONLY_AST, "user text was compiled to code"
        return real_compile(source, filename, mode, flags, *args, **kw)

    def forbidden(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("eval/exec was called")

    monkeypatch.setattr(builtins, "compile", syntax_tree_only)
    monkeypatch.setattr(builtins, "eval", forbidden)
    monkeypatch.setattr(builtins, "exec", forbidden)
    monkeypatch.setattr(builtins, "__import__", forbidden)
    with pytest.raises(ConfigError) as info:
        compile_expression(text, NAMES)
    monkeypatch.undo()
    assert "is not allowed" in str(info.value) or "unknown" in str(info.value)


def test_expression_results_are_real_not_complex() -> None:
    # Python would give a complex number here; a reward must be real or fail loudly.
    assert isinstance((-8.0) ** (1 / 3), complex)
    with pytest.raises(BridgeError, match="math domain error"):
        compile_expression("x ** (1/3)", NAMES)(np.array([-8.0, 0, 0, 0]))
    assert cmath.isfinite(compile_expression("abs(x) ** (1/3)", NAMES)(np.array([-8.0, 0, 0, 0])))
