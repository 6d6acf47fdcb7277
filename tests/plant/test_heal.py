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
from bridge.errors import FmuError, StepError
from bridge.experiment.config import Experiment, parse_experiment
from bridge.experiment.validate import resolve_fmu, timing
from bridge.experiment.yaml_text import parse_yaml
from bridge.fmu import read_model_info
from bridge.net.requests import BadRequest, RequestRules
from bridge.plant.experiment_model import experiment_plant_spec
from bridge.plant.isolated import IsolatedFmuPlant
from bridge.plant.local import LocalFmuPlant
from bridge.serving.experiment import served_by

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
    "in-process": lambda e: LocalFmuPlant(experiment_plant_spec(e)),
    "isolated": lambda e: IsolatedFmuPlant(experiment_plant_spec(e), timeout_s=30.0),
}
# the isolated plant is a child process: that case is an integration test
KINDS = [pytest.param(k, marks=pytest.mark.integration) if k == "isolated" else k for k in PLANTS]


def refused(env: FmuEnv, kind: str, episode: int) -> None:
    """The refused reset: the plant's StepError saying what failed, what was set and how to go on."""
    with pytest.raises(StepError) as caught:
        env.reset(options={"scenario": "refused"})
    error = caught.value
    where = "in-process" if kind == "in-process" else "child process"
    assert str(error).startswith(
        f"FMU {resolve_fmu(EXPERIMENT).name} ({where}): the model's initialisation failed at reset of "
        f"episode {episode}: typed: fmi2ExitInitializationMode failed"
    ), str(error)
    assert error.what == "the model's initialisation failed" and error.step is None
    assert error.detail.endswith("; this reset set real_param = 5000.0"), error.detail
    assert error.hint.startswith("the FMU refused to initialise with the values this reset set")
    assert error.hint.endswith("the next reset() instantiates it afresh")
    assert "real_param = 5000 is above init_fails_above = 1000" in " ".join(error.log)  # the FMU's why
    assert str(error).endswith(
        "FMU log (most recent last):\n  [ERROR] logStatusError: typed: real_param = 5000 is above "
        "init_fails_above = 1000: initialisation refused (test hook)"
    ), str(error)
    assert isinstance(error, FmuError)  # code that caught the bare FmuError still catches it


@pytest.mark.parametrize("kind", KINDS)
def test_a_refused_initialisation_heals_at_the_next_reset(kind: str) -> None:
    plant = PLANTS[kind](EXPERIMENT)
    with FmuEnv(EXPERIMENT, plant=plant) as env:  # type: ignore[arg-type]
        env.reset(options={"scenario": "fine"})
        assert env.plant.unusable is None
        refused(env, kind, 2)
        assert "failed" in str(env.plant.unusable), env.plant.unusable  # what a node's health can say
        for episode in range(2):
            env.reset(options={"scenario": "fine"})
            assert env.plant.unusable is None
            trace = [env.step(np.array([0.5], dtype=np.float32))[0] for _ in range(3)]
            assert [list(o) for o in trace] == [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]], (episode, trace)


@pytest.mark.parametrize("kind", KINDS)
def test_a_first_reset_whose_initialisation_is_refused_is_the_same_error_and_heals(kind: str) -> None:
    with FmuEnv(EXPERIMENT, plant=PLANTS[kind](EXPERIMENT)) as env:  # type: ignore[arg-type]
        refused(env, kind, 1)  # the instance is created by this reset
        refused(env, kind, 2)  # a refused reset after a refused one: the same words
        env.reset(options={"scenario": "fine"})
        trace = [env.step(np.array([0.5], dtype=np.float32))[0].tolist() for _ in range(3)]
        assert trace == [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]]


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
