"""BatchPlant over model exchange with a fixed-step solver: one native call integrates the batch.

The native batch loop must give the per-instance path's values bit for bit, including samples
that stop at state events (bouncing ball), time events inside a sample (stair) and termination
asked by one instance (cart-pole at its track limit); the stair's values are also checked against
its closed form.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.config import load_experiment
from bridge.plant.batch import BatchPlant
from bridge.plant.experiment_model import experiment_plant_spec

MODEL = """\
model: {{fmu: 'example:{name}:{version}', interface: me, solver: rk4, solver_substeps: {substeps},
        step_size: {h}, sampling_time: {sampling}, episode_duration: {duration}}}
{actions}
observations: {{outputs: [{outputs}]}}
reward: {{terms: [{{alive: 1.0}}]}}
"""
CASES: dict[str, dict[str, Any]] = {
    # time events every 0.1 s fall inside samples of 0.04 s (two FMU steps of 0.02 s)
    "stair": dict(substeps=3, h=0.02, sampling=0.04, duration=2.0, action="rate", outputs="x, y, held"),
    "bouncing_ball": dict(substeps=4, h=0.01, sampling=0.01, duration=3.0, action="", outputs="h, v"),
    "cartpole": dict(substeps=5, h=0.02, sampling=0.02, duration=4.0, action="force",
                     outputs="x, x_dot, theta, theta_dot"),
}  # fmt: skip


def experiment(tmp_path: Path, name: str, version: str) -> Path:
    case = dict(CASES[name])
    u = case.pop("action")
    actions = (
        f"actions: {{inputs: [{u}], low: {{{u}: -10}}, high: {{{u}: 10}}}}" if u else "actions: {inputs: []}"
    )
    path = tmp_path / f"{name}{version[0]}.yaml"
    path.write_text(MODEL.format(name=name, version=version, actions=actions, **case))
    return path


def open_plant(path: Path, n: int, native: bool, threads: int = 1) -> BatchPlant:
    exp = load_experiment(path)
    plant = BatchPlant(experiment_plant_spec(exp), n, native=native, threads=threads)
    plant.bind(list(exp.actions.inputs), list(exp.observations.outputs))
    return plant


def episode(plant: BatchPlant, values: list[dict[str, float]], inputs: np.ndarray) -> dict[str, Any]:
    """Reset every instance, step through ``inputs``; re-reset the ones that end, as an env does."""
    for i, v in enumerate(values):
        plant.reset(i, v, inputs[0, i].tolist() or None)
    rows, ended, ks = [], [], []
    for u in inputs:
        result = plant.step(u)
        assert result.errors == {}
        rows.append(result.outputs.copy())
        ended.append(result.terminated.copy())
        ks.append(plant.k.copy())
        for i in np.flatnonzero(result.terminated).tolist():
            plant.reset(i, values[i], u[i].tolist() or None)
    return {"outputs": np.array(rows), "terminated": np.array(ended), "k": np.array(ks)}


def both_paths(path: Path, values: list[dict[str, float]], inputs: np.ndarray) -> dict[str, Any]:
    runs = {}
    for native, threads in ((True, 1), (True, 2), (False, 1)):  # two threads: two slices in C
        with open_plant(path, len(values), native, threads) as plant:
            runs[native, threads] = episode(plant, values, inputs)
            assert plant.native is native
    for run in (runs[True, 2], runs[False, 1]):
        for key in runs[True, 1]:
            np.testing.assert_array_equal(runs[True, 1][key], run[key], err_msg=key)
    return runs[True, 1]


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_time_events_inside_samples(tmp_path: Path, version: str) -> None:
    rng = np.random.default_rng(1)
    n, samples = 5, 40
    inputs = np.repeat(rng.uniform(0.5, 2.0, size=(1, n, 1)), samples, axis=0)  # a constant rate each
    x0 = rng.uniform(-1, 1, size=n)
    run = both_paths(experiment(tmp_path, "stair", version), [{"x0": float(v)} for v in x0], inputs)
    t = 0.04 * np.arange(1, samples + 1)[:, None]
    rate = inputs[0, :, 0][None, :]
    np.testing.assert_allclose(run["outputs"][:, :, 0], x0 + rate * t, rtol=0, atol=1e-12)
    tick = np.floor(t / 0.1 + 1e-9) * 0.1  # the last tick at or before t: held samples x there
    np.testing.assert_allclose(run["outputs"][:, :, 2], x0 + rate * tick, rtol=0, atol=1e-12)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_state_events_bounce_alike(tmp_path: Path, version: str) -> None:
    heights = [{"h0": h} for h in (0.5, 1.0, 1.5, 2.0)]
    run = both_paths(experiment(tmp_path, "bouncing_ball", version), heights, np.zeros((300, 4, 0)))
    v = run["outputs"][:, :, 1]
    assert (np.diff(np.sign(v), axis=0) > 0).sum(axis=0).min() >= 2  # every ball bounced twice


def test_one_instance_terminating_alone(tmp_path: Path) -> None:
    limits = [{"track_limit": 0.0}, {"track_limit": 0.3}, {"track_limit": 0.0}]
    inputs = np.full((120, 3, 1), 5.0)  # pushes every cart along; only instance 1 has a track end
    run = both_paths(experiment(tmp_path, "cartpole", "2.0"), limits, inputs)
    ended = run["terminated"]
    assert ended[:, 1].any() and not ended[:, 0].any() and not ended[:, 2].any()


def test_an_fmu_from_another_tool(tmp_path: Path, eta_ctrl_fmus: dict[str, Path]) -> None:
    """Dymola's damped oscillator (FMI 2.0 ME, inputs u and f): the native batch loop equals the
    per-instance path bit for bit, and follows Dymola's own co-simulation solver."""
    fmu = eta_ctrl_fmus["damped_oscillator"]
    text = (
        f"model: {{fmu: '{fmu}', interface: me, solver: rk4, solver_substeps: 10, step_size: 0.01,"
        " episode_duration: 2.0}\n"
        "actions: {inputs: [u, f], low: {u: -1, f: -5}, high: {u: 1, f: 5}}\n"
        "observations: {outputs: [s, v]}\nreward: {terms: [{alive: 1.0}]}\n"
    )
    path = tmp_path / "oscillator.yaml"
    path.write_text(text)
    rng = np.random.default_rng(5)
    inputs = np.repeat(rng.uniform(-1, 1, size=(20, 3, 2)) * [0.5, 3.0], 10, axis=0)  # held 0.1 s
    springs = [{"springDamper.c": c} for c in (5.0, 10.0, 20.0)]
    run = both_paths(path, springs, inputs)
    cs_path = tmp_path / "oscillator_cs.yaml"
    cs_path.write_text(text.replace("interface: me, solver: rk4, solver_substeps: 10,", "interface: cs,"))
    with BatchPlant(experiment_plant_spec(load_experiment(cs_path)), 3, native=True) as cs:
        cs.bind(["u", "f"], ["s", "v"])
        reference = episode(cs, springs, inputs)["outputs"]
    assert np.ptp(reference[:, :, 0]) > 0.05  # it really moved
    np.testing.assert_allclose(run["outputs"], reference, rtol=0, atol=5e-4)
