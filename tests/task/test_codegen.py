"""The Task's generated functions: one source, evaluated on floats and on numpy columns, gives the
same bits (a square is ``q * q``, never ``pow``), and the termination check treats NaN as outside."""

from __future__ import annotations

import math

import numpy as np

from bridge.experiment.reward import RewardTerm
from bridge.task.codegen import (
    batch_observation,
    batch_reward_terms,
    observation,
    observation_source,
    reward_terms,
    termination,
    terms_source,
)

N = 20_000


def _terms() -> list[RewardTerm]:
    return [
        RewardTerm.model_validate({"alive": 1.0}),
        RewardTerm.model_validate({"signal": {"name": "a", "norm": "squared", "weight": 0.5, "scale": 0.2}}),
        RewardTerm.model_validate({"signal": {"name": "b", "norm": "abs", "weight": 0.1, "scale": 2.4}}),
        RewardTerm.model_validate({"tracking": {"output": "a", "reference": "r", "norm": "squared"}}),
        RewardTerm.model_validate({"effort": {"name": "u", "norm": "squared", "weight": 0.01, "scale": 3.0}}),
        RewardTerm.model_validate({"rate": {"name": "u", "norm": "squared", "weight": 0.3, "scale": 0.7}}),
    ]


def test_squares_are_products_not_powers() -> None:
    source = terms_source(_terms(), {"a": 0, "b": 1, "r": 2}, ["u"])
    assert "**" not in source and "pow" not in source


def test_reward_terms_give_the_same_bits_on_floats_and_on_columns() -> None:
    """Values spread over many magnitudes, where ``pow`` and numpy's SIMD ``power`` disagree with
    ``x * x`` in the last bit for a few percent of values on some CPUs."""
    rng = np.random.default_rng(7)
    s = rng.normal(size=(N, 3)) * 10.0 ** rng.integers(-3, 4, size=(N, 3))
    u, p = rng.normal(size=(N, 1)) * 5.0, rng.normal(size=(N, 1)) * 5.0
    index = {"a": 0, "b": 1, "r": 2}
    scalar = reward_terms(_terms(), index, ["u"])
    batch = batch_reward_terms(_terms(), index, ["u"])
    expected = np.array([scalar(s[i].tolist(), u[i].tolist(), p[i].tolist()) for i in range(N)])
    got = batch(s.T, u.T, p.T)
    np.testing.assert_array_equal(got, expected)
    a = s[:, 0] / 0.2  # and the square is the exact product
    np.testing.assert_array_equal(-0.5 * (a * a), np.array([-0.5 * (x * x) for x in a.tolist()]))


def test_observation_gives_the_same_bits_on_floats_and_on_columns() -> None:
    rng = np.random.default_rng(3)
    s, u, nz = rng.normal(size=(N, 3)) * 3.0, rng.normal(size=(N, 1)), rng.normal(size=(N, 1)) * 0.01
    source = observation_source(
        ["s[0] + nz[0]", "s[1] - s[2]", "u[0]"], [0.1, 0.0, -0.5], [1 / 2.4, 1 / 3, 0.7], 4.0
    )
    scalar, batch = observation(source), batch_observation(source)
    expected = np.array([scalar(s[i].tolist(), u[i].tolist(), nz[i].tolist()) for i in range(N)])
    got = np.stack(batch(s.T, u.T, nz.T), axis=1)
    np.testing.assert_array_equal(got, expected)
    assert np.abs(got).max() == 4.0  # the clip is reached and applied alike


def test_termination_names_the_first_bound_left_and_counts_nan_as_outside() -> None:
    reason = termination({"x": (-1.0, 1.0), "y": (None, 2.0), "z": (0.0, None)}, {"x": 0, "y": 1, "z": 2})
    assert reason([0.0, 0.0, 0.0]) is None
    assert reason([1.5, 3.0, -1.0]) == "bounds:x"
    assert reason([0.0, 3.0, -1.0]) == "bounds:y"
    assert reason([0.0, 0.0, -1.0]) == "bounds:z"
    assert reason([math.nan, 0.0, 0.0]) == "bounds:x"
