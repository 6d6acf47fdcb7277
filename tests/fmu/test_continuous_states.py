"""Model's continuous states: what linearisation reads and sets, through Model, not FMPy."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.errors import FmuError, VariableError
from bridge.fmu import Model
from bridge.models import example_fmu


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_states_set_and_derivatives_follow_them(version: str) -> None:
    with Model(example_fmu("cartpole", version, "me"), interface="me") as model:
        model.initialize({"theta0": 0.1})
        x = model.continuous_states()
        assert x.tolist() == [0.0, 0.0, 0.1, 0.0]  # x, x_dot, theta, theta_dot
        moved = x + np.array([0.5, 0.25, 0.0, -0.75])
        model.set_continuous_states(moved)
        np.testing.assert_array_equal(model.continuous_states(), moved)
        dx = model.derivatives()
        # the positions' derivatives are the velocities just set (x' = x_dot, theta' = theta_dot)
        assert (dx[0], dx[2]) == (0.25, -0.75) and np.isfinite(dx).all()
        with pytest.raises(VariableError, match="4 continuous states expected"):
            model.set_continuous_states([1.0, 2.0])


def test_a_co_simulation_instance_has_no_state_access() -> None:
    with Model(example_fmu("cartpole", "2.0", "cs")) as model:
        model.initialize()
        with pytest.raises(FmuError, match="needs an initialised model-exchange instance"):
            model.continuous_states()
