"""The system's native master on models alone: no plant, no experiment, no system file.

``bridge.fmu.system_step.NativeMaster`` takes models (with their signal groups), links as array
positions and the input and output arrays, and says what happened. Held here to a Jacobi loop
written with ``Model``'s own calls (set the inputs, advance, read the outputs), bit for bit, over a
cart pushed off its track until it asks to stop.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from bridge.fmu import Model
from bridge.fmu.system_step import Coupling, Happened, NativeMaster, Unit, library, usable
from bridge.models import example_fmu

FORCE = 4.0  # N on the cart through the gain: it leaves its 0.5 m track within a few hundred steps


@pytest.fixture
def models() -> Iterator[tuple[Model, Model]]:
    gain = Model(example_fmu("feedthrough"), step_size_s=0.02)
    cart = Model(example_fmu("cartpole"), step_size_s=0.01)  # two steps per macro step of 0.02 s
    with gain, cart:
        gain.initialize()
        cart.initialize({"track_limit": 0.5})
        yield gain, cart


def python_loop(gain: Model, cart: Model, macro_steps: int) -> tuple[list[list[float]], int]:
    """Jacobi by hand: cart.force gets gain.y of t, gain.u the external force; both step to t + H."""
    rows, y_gain = [], gain.get(["y"])["y"]
    for done in range(macro_steps):
        gain.set({"u": FORCE})
        cart.set({"force": y_gain})
        stopped = gain.advance(1) | cart.advance(2)
        y_gain = gain.get(["y"])["y"]
        rows.append([y_gain, *cart.get(["x", "theta"]).values()])
        if stopped:
            return rows, done + 1
    return rows, macro_steps


def native_master(gain: Model, cart: Model) -> tuple[NativeMaster, list[np.ndarray], list[np.ndarray]]:
    units = [
        Unit("gain", gain, gain.signals(["u"], writable=True), gain.signals(["y"]), 1),
        Unit("cart", cart, cart.signals(["force"], writable=True), cart.signals(["x", "theta"]), 2),
    ]
    assert all(usable(u, iterating=False) for u in units)
    function = library()
    if function is None:
        pytest.skip("no C compiler: the native master cannot be built here")
    master = NativeMaster(
        function, units, [Coupling(0, 0, 1, 0)], gauss_seidel=False, external=[(0, 0)], observed=[(1, 0)]
    )
    inputs = [np.array([FORCE]), np.array([0.0])]
    outputs = [np.array([gain.get(["y"])["y"]]), np.array(list(cart.get(["x", "theta"]).values()))]
    inputs, outputs = master.bind(inputs, outputs)
    return master, inputs, outputs


def test_the_native_master_on_models_equals_a_jacobi_loop_of_model_calls(models: tuple[Model, Model]) -> None:
    gain, cart = models
    master, _, outputs = native_master(gain, cart)
    rows: list[list[float]] = []
    happened = Happened(0)
    while not happened.stopped and len(rows) < 2000:
        assert master.refused() is None
        happened = master.run(1)
        rows.append([outputs[0][0], outputs[1][0], outputs[1][1]])
    assert happened.stopped and not happened.failed and happened.stepped == 2
    assert cart.terminated and not gain.terminated  # the cart asked to stop, the gain did not
    assert master.refused() == 1  # the cart cannot step again until it is reset
    assert abs(rows[-1][1]) >= 0.5 - 1e-3  # it stopped at the end of its track

    steps = len(rows)
    reference = (
        Model(example_fmu("feedthrough"), step_size_s=0.02),
        Model(example_fmu("cartpole"), step_size_s=0.01),
    )
    with reference[0], reference[1]:
        reference[0].initialize()
        reference[1].initialize({"track_limit": 0.5})
        expected, stopped_at = python_loop(*reference, 2 * steps)
        # their own clocks, advanced in C: the cart stopped inside its last macro step, as by hand
        assert (gain.step_index, cart.step_index) == (steps, reference[1].step_index)
        assert reference[0].step_index == steps and cart.step_index in (2 * steps - 1, 2 * steps)
    assert stopped_at == steps
    np.testing.assert_array_equal(np.array(rows), np.array(expected))


def test_a_sample_sets_the_external_input_and_returns_the_observation(models: tuple[Model, Model]) -> None:
    gain, cart = models
    master, inputs, _ = native_master(gain, cart)
    observation = master.sample([FORCE], 5)
    assert observation is not None and master.happened == Happened(5)
    assert inputs[0][0] == FORCE and inputs[1][0] == FORCE  # scattered, then passed on by the link
    assert observation.shape == (1,) and observation[0] == cart.get(["x"])["x"] > 0.0
    assert cart.step_index == 10 and gain.step_index == 5
