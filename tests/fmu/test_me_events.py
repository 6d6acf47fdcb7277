"""Model exchange by the FMI call sequence: discrete inputs and tunable parameters in event mode,
time events kept across state snapshots, FMI 1.0 model exchange; checked against the co-simulation
variant, a closed form and FMPy's simulate_fmu."""

from __future__ import annotations

import numpy as np
import pytest
from fmpy import simulate_fmu

from bridge.fmu import Model
from bridge.models import example_fmu

H, PERIOD = 0.05, 0.1
STAIR_OUT = ["x", "stair", "held", "y"]


def step_schedule(k: int) -> tuple[float, int]:
    """(rate, step) written before sample k: both change during the run."""
    return (1.0 + 0.5 * (k // 4), [1, 3, -2][(k // 3) % 3])


def run_stair(model: Model, samples: int, *, tunable: bool = True) -> np.ndarray:
    inputs = model.signals(["rate", "step"], writable=True)
    outputs = model.signals(STAIR_OUT)
    rows = [outputs.read()]
    for k in range(samples):
        inputs.write(list(step_schedule(k)))
        if k == 5:  # a discrete input and (FMI 2.0/3.0) a tunable parameter, mid-run
            model.set({"step": 4, **({"offset": 10.0} if tunable else {})})
        model.advance(1)
        rows.append(outputs.read())
    return np.array(rows)


def closed_form(samples: int, *, tunable: bool = True) -> np.ndarray:
    x, stair, held, offset = 0.0, 0, 0.0, 0.0
    rows = [(x, stair, held, offset)]
    for k in range(samples):
        rate, step = step_schedule(k)
        if k == 5:
            offset, step = (10.0 if tunable else 0.0), 4
        x += rate * H
        if (k + 1) % 2 == 0:  # a tick (period 2 samples) at the end of every second sample
            stair, held = stair + step, x
        rows.append((x, stair, held, x + offset))
    return np.array(rows)


@pytest.mark.parametrize("version", ["1.0", "2.0", "3.0"])
def test_discrete_inputs_and_tunable_parameters_change_during_a_me_run(version: str) -> None:
    with Model(example_fmu("stair", version, "me"), step_size_s=H) as model:
        model.initialize({"period": PERIOD})
        model.set({"step": 2})  # before the first step, as the env does at reset
        model.set({"step": 1})
        ours = run_stair(model, 20, tunable=version != "1.0")  # FMI 1.0 has no tunable parameters
    np.testing.assert_allclose(ours, closed_form(20, tunable=version != "1.0"), rtol=0, atol=1e-9)
    assert ours[-1, 1] != 0  # the stair really climbed


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_me_equals_co_simulation_of_the_same_model(version: str) -> None:
    runs = {}
    for interface in ("cs", "me"):
        with Model(example_fmu("stair", version, interface), step_size_s=H) as model:
            model.initialize({"period": PERIOD})
            runs[interface] = run_stair(model, 20)
    np.testing.assert_allclose(runs["me"], runs["cs"], rtol=0, atol=1e-9)


@pytest.mark.parametrize("policy", ["restore", "reset", "reinstantiate", "auto"])
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_time_events_give_the_same_trajectory_in_every_episode(version: str, policy: str) -> None:
    episodes = []
    with Model(example_fmu("stair", version, "me"), step_size_s=H, reset_policy=policy) as model:
        for _ in range(5):
            model.reset({"period": PERIOD})
            episodes.append(run_stair(model, 12))
    np.testing.assert_allclose(episodes[0], closed_form(12), rtol=0, atol=1e-9)
    for episode in (1, 4):
        np.testing.assert_array_equal(episodes[episode], episodes[0])


def test_fmi1_model_exchange_matches_fmpy_simulate_fmu() -> None:
    path = example_fmu("cartpole", "1.0", "me")
    start = {"theta0": 0.05, "m_pole": 0.2}
    with Model(path, step_size_s=0.02, tolerance=1e-8) as model:
        model.initialize(start)
        inputs, outputs = model.signals(["force"], writable=True), model.signals(["x", "theta"])
        rows = [outputs.read()]
        for _ in range(50):
            inputs.write([3.0])
            model.advance(1)
            rows.append(outputs.read())
    signal = np.array([(0.0, 3.0), (1.0, 3.0)], dtype=[("time", np.float64), ("force", np.float64)])
    ref = simulate_fmu(
        str(path),
        fmi_type="ModelExchange",
        start_values=start,
        input=signal,
        stop_time=1.0,
        output_interval=0.02,
        relative_tolerance=1e-8,
        output=["x", "theta"],
    )
    expected = np.column_stack([ref["x"], ref["theta"]])[:51]
    np.testing.assert_allclose(np.array(rows), expected, rtol=0, atol=2e-5)  # two CVode runs
    assert abs(rows[-1][1] - rows[0][1]) > 0.1  # the pole really moved


def test_fmi1_me_stair_matches_fmpy_simulate_fmu() -> None:
    path = example_fmu("stair", "1.0", "me")
    with Model(path, step_size_s=H) as model:
        model.initialize({"step": 2, "rate": 0.5})
        outputs = model.signals(["x", "stair", "held"])
        rows = [outputs.read()]
        for _ in range(20):
            model.advance(1)
            rows.append(outputs.read())
    ref = simulate_fmu(
        str(path),
        fmi_type="ModelExchange",
        start_values={"step": 2, "rate": 0.5},
        stop_time=1.0,
        output_interval=H,
        output=["x", "stair", "held"],
    )
    # FMPy records an event twice (before and after it): keep the last row at each time.
    times = np.asarray(ref["time"])
    last = [int(np.flatnonzero(np.isclose(times, k * H))[-1]) for k in range(21)]
    expected = np.column_stack([ref[n][last] for n in ("x", "stair", "held")])
    np.testing.assert_allclose(np.array(rows), expected, rtol=0, atol=1e-9)
    assert rows[-1][1] == 20  # ten ticks of 2
