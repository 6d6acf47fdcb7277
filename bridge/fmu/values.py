"""Checking and converting single values between Python and the FMI C types.

Integer values stay Python ints end to end (never a float64 round trip), so 64-bit values
reach the FMU exactly, and every integer is checked against the range of its FMI type.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bridge.errors import VariableError
from bridge.fmu.description import Variable

# Ranges of the FMI integer types; FMI 1.0/2.0 Integer (and Enumeration) are 32 bit, FMI 3.0
# Enumeration is 64 bit.
INT_RANGES: dict[str, tuple[int, int]] = {
    "Int8": (-(2**7), 2**7 - 1),
    "UInt8": (0, 2**8 - 1),
    "Int16": (-(2**15), 2**15 - 1),
    "UInt16": (0, 2**16 - 1),
    "Int32": (-(2**31), 2**31 - 1),
    "UInt32": (0, 2**32 - 1),
    "Int64": (-(2**63), 2**63 - 1),
    "UInt64": (0, 2**64 - 1),
}


def int_range(var_type: str, fmi_major: int) -> tuple[int, int]:
    """The range of an integer or enumeration type in an FMI version."""
    if var_type == "Enumeration":
        return INT_RANGES["Int64" if fmi_major == 3 else "Int32"]
    return INT_RANGES[var_type]


def is_integer_type(var_type: str) -> bool:
    return var_type in INT_RANGES or var_type == "Enumeration"


def range_error(model_name: str, var: Variable, value: Any, fmi_major: int) -> VariableError:
    low, high = int_range(var.type, fmi_major)
    if isinstance(value, float) and math.isfinite(value) and value == int(value):
        value = int(value)
    return VariableError(
        f"{model_name}: {var.name}={value} is out of range for its type {var.type} "
        f"(expected a whole number in [{low}, {high}]); clip or map the value before writing it"
    )


def to_c(var: Variable, value: Any, model_name: str, fmi_major: int) -> Any:
    """Check ``value`` against ``var``'s type and convert it for the FMI call."""
    where = f"{model_name}: {var.name!r} ({var.type})"
    if var.type == "String":
        if not isinstance(value, str):
            raise VariableError(f"{where} expects a str, got {value!r}")
        return value.encode()
    if var.type == "Binary":
        if not isinstance(value, bytes | bytearray | memoryview):
            raise VariableError(f"{where} expects bytes, got {type(value).__name__} {value!r:.60}")
        return bytes(value)
    if isinstance(value, str) and var.type == "Enumeration":
        items = dict(var.enum_items)
        if value not in items:
            raise VariableError(f"{where}: {value!r} is not one of {list(items)}")
        return items[value]
    if is_integer_type(var.type):
        return _to_int(var, value, where, model_name, fmi_major)
    number = _finite(value, where)
    if var.type.startswith("Float"):
        return number
    if var.type == "Boolean":
        return _boolean(number, where, value, fmi_major)
    raise VariableError(f"{where}: values of type {var.type} cannot be set")


def _finite(value: Any, where: str) -> float:
    if isinstance(value, bool | np.bool_):
        return float(value)
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise VariableError(f"{where} expects a number, got {value!r}") from None
    if not math.isfinite(number):
        raise VariableError(f"{where} got {value!r}: expected a finite number")
    return number


def _to_int(var: Variable, value: Any, where: str, model_name: str, fmi_major: int) -> int:
    if isinstance(value, int | np.integer) and not isinstance(value, bool):
        exact = int(value)  # exact: large 64-bit values must not pass through a float
    else:
        number = _finite(value, where)
        if number != int(number):
            raise VariableError(f"{where} expects a whole number, got {value!r}")
        exact = int(number)
    low, high = int_range(var.type, fmi_major)
    if not low <= exact <= high:
        raise range_error(model_name, var, value, fmi_major)
    return exact


def _boolean(number: float, where: str, value: Any, major: int) -> Any:
    if number not in (0.0, 1.0):
        raise VariableError(f"{where} expects True/False (or 0/1), got {value!r}")
    if major == 1:  # FMI 1.0 booleans are chars
        return b"\x01" if number else b"\x00"
    return bool(number)


def from_c(raw: Any, var_type: str) -> Any:
    if var_type == "String":
        return raw.decode(errors="replace") if raw is not None else ""
    if var_type == "Boolean":
        return raw not in (b"\x00", 0, False)
    if var_type.startswith("Float"):
        return float(raw)
    return int(raw)
