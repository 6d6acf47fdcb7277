"""Failures that heal: an FMU that refuses its initialisation works again at the next reset.

A reset value the FMU refused during initialisation once left the instance half-initialised, and
every later reset failed (``fmi2SetupExperiment is not allowed in error``) while the plant looked
healthy. The typed test model refuses to initialise when ``real_param > init_fails_above``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from bridge.env import FmuEnv
from bridge.errors import BridgeError
from bridge.experiment.config import Experiment, parse_experiment
from bridge.experiment.validate import resolve_fmu, timing
from bridge.experiment.yaml_text import parse_yaml
from bridge.fmu import read_model_info
from bridge.net.requests import BadRequest, RequestRules
from bridge.net.served import served_by
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant

TEXT = """
model: {fmu: 'example:typed', step_size: 0.1, episode_duration: 1.0}
actions: {inputs: [real_in], low: {real_in: -1}, high: {real_in: 1}}
observations: {outputs: [real_out, counter]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {parameters: {real_param: 2.0}}
  refused: {parameters: {real_param: 5000.0}}
"""
EXPERIMENT = parse_experiment(parse_yaml(TEXT))
PLANTS: dict[str, Callable[[Experiment], object]] = {
    "in-process": LocalFmuPlant,
    "isolated": lambda e: IsolatedFmuPlant(e, timeout_s=30.0),
}


@pytest.mark.parametrize("kind", list(PLANTS))
def test_a_refused_initialisation_heals_at_the_next_reset(kind: str) -> None:
    plant = PLANTS[kind](EXPERIMENT)
    with FmuEnv(EXPERIMENT, plant=plant) as env:  # type: ignore[arg-type]
        env.reset(options={"scenario": "fine"})
        assert env.plant.unusable is None
        with pytest.raises(BridgeError, match="real_param = 5000 is above init_fails_above = 1000"):
            env.reset(options={"scenario": "refused"})
        assert "failed" in str(env.plant.unusable), env.plant.unusable  # what a node's health can say
        for episode in range(2):
            env.reset(options={"scenario": "fine"})
            assert env.plant.unusable is None
            trace = [env.step(np.array([0.5], dtype=np.float32))[0] for _ in range(3)]
            assert [list(o) for o in trace] == [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]], (episode, trace)


def test_reset_values_are_bounded_by_the_experiments_own_ranges() -> None:
    experiment = parse_experiment(
        parse_yaml(
            TEXT
            + "randomization: {parameters: {gain: {uniform: [1.0, 3.0]},"
            + " init_fails_above: {normal: [1000, 1]}}}"
        )
    )
    info = read_model_info(resolve_fmu(experiment))
    rules = RequestRules(served_by(experiment, info, timing(experiment, info)), info.variables)
    assert rules.input_names == ("real_in",)
    assert rules.values({"real_param": 2.0, "gain": 2.5}) == {"real_param": 2.0, "gain": 2.5}
    assert rules.values({"real_param": 5000.0}) == {"real_param": 5000.0}  # a scenario sets it
    with pytest.raises(
        BadRequest, match=r"'real_param' \(Float64\) = 5001 is outside the experiment's range \[2, 5000\]"
    ):
        rules.values({"real_param": 5001.0})
    with pytest.raises(
        BadRequest, match=r"'gain' \(Float64\) = 7 is outside the experiment's range \[1, 3\]"
    ):
        rules.values({"gain": 7.0})
    assert rules.values({"init_fails_above": 1e9}) == {"init_fails_above": 1e9}  # a normal draw: any value
