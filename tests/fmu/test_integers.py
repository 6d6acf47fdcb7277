"""Integers on every write path: exact at both ends of 64 bit, range-checked with a clear message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.errors import VariableError
from bridge.fmu import Model

INT64_MAX, UINT64_MAX = 2**63 - 1, 2**64 - 1


def test_64_bit_extremes_reach_the_fmu_exactly_through_a_signal_group(typed_fmu3: Path) -> None:
    with Model(typed_fmu3, step_size_s=0.1) as model:
        model.initialize()
        inputs = model.signals(["real_in", "int64_in", "uint64_in"], writable=True)
        for int64, uint64 in ((INT64_MAX, UINT64_MAX), (-(2**63), 0), (2**53 + 1, 2**63 + 1)):
            inputs.write([0.5, int64, uint64])
            model.advance(1)
            assert model.get(["int64_out", "uint64_out"]) == {"int64_out": int64, "uint64_out": uint64}
        inputs.write(np.array([0.5, INT64_MAX, UINT64_MAX], dtype=object))
        model.advance(1)
        assert model.get(["int64_out", "uint64_out"]) == {"int64_out": INT64_MAX, "uint64_out": UINT64_MAX}


def test_64_bit_extremes_reach_the_fmu_exactly_through_set_and_reset(typed_fmu3: Path) -> None:
    with Model(typed_fmu3, step_size_s=0.1) as model:
        model.initialize({"int64_in": INT64_MAX, "uint64_in": UINT64_MAX})
        assert model.get(["int64_in", "uint64_in"]) == {"int64_in": INT64_MAX, "uint64_in": UINT64_MAX}
        model.set({"int64_in": -(2**63), "uint64_in": 2**64 - 2})
        model.advance(1)
        assert model.get(["int64_out", "uint64_out"]) == {"int64_out": -(2**63), "uint64_out": 2**64 - 2}
        model.reset({"uint64_in": UINT64_MAX})
        assert model.get(["uint64_in"]) == {"uint64_in": UINT64_MAX}


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        (
            "int64_in",
            2**63,
            r"int64_in=9223372036854775808 .*Int64.*-9223372036854775808, 9223372036854775807\]",
        ),
        ("uint64_in", 2**64, r"uint64_in=18446744073709551616 .*UInt64.*\[0, 18446744073709551615\]"),
        ("uint64_in", -1, r"uint64_in=-1 .*UInt64"),
        ("int64_in", float(2**63), r"int64_in=9223372036854775808 .*Int64"),
        ("integer_in", 2**32 + 5, r"integer_in=4294967301 .*Int32.*\[-2147483648, 2147483647\]"),
        ("int8_in", 128, r"int8_in=128 .*Int8.*\[-128, 127\]"),
        ("uint8_in", -1, r"uint8_in=-1 .*UInt8.*\[0, 255\]"),
    ],
)
def test_out_of_range_integers_are_refused_on_every_path(
    typed_fmu3: Path, name: str, value: int | float, message: str
) -> None:
    with Model(typed_fmu3, step_size_s=0.1) as model:
        with pytest.raises(VariableError, match=message):
            model.initialize({name: value})
        model.initialize()
        with pytest.raises(VariableError, match=message):
            model.set({name: value})
        with pytest.raises(VariableError, match=message):
            model.reset({name: value})
        group = model.signals(["real_in", name], writable=True)
        with pytest.raises(VariableError, match=message):
            group.write([0.0, value])
        model.advance(1)  # nothing reached the FMU: it still steps
        assert model.get([name])[name] == 0


def test_fmi2_integer_range_is_32_bit_on_every_path(typed_fmu2: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.1) as model:
        with pytest.raises(VariableError, match=r"integer_param=4294967301 .*Int32"):
            model.initialize({"integer_param": 2**32 + 5})
        model.initialize({"integer_param": 2**31 - 1})
        assert model.get(["integer_param"]) == {"integer_param": 2**31 - 1}
        with pytest.raises(VariableError, match=r"integer_in=-2147483649 .*Int32"):
            model.signals(["real_in", "integer_in"], writable=True).write([0.0, -(2**31) - 1])
