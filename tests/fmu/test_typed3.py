"""FMI 3.0 arrays, Binary and clocks on our own C model ``typed3`` (no third-party FMU has all three).

``typed3``: input ``u[3]``; output ``y[2,3]`` with row 1 = ``u`` held over the last step and row 2 =
its time integral; ``data_out`` = ``data_in`` reversed, with ``data_size`` and ``data_sum``; a clock
``tick`` with a constant interval of 0.1 s and ``ticks``, the intervals completed since the start.
References: closed forms, FMPy's ``simulate_fmu`` and FMPy's validator.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu
from typer.testing import CliRunner

from bridge.cli.main import app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import VariableError
from bridge.experiment.init import q
from bridge.fmu import Model, read_model_info
from tests.conftest import example_fmu

STEP_S = 0.1


@pytest.fixture(scope="module")
def typed3() -> Path:
    return example_fmu("typed3", "3.0", "cs")


def test_fmpy_validator_accepts_typed3(typed3: Path) -> None:
    assert validate_fmu(str(typed3)) == []


def test_inspect_shows_array_dimensions_binary_variables_and_the_clock(typed3: Path) -> None:
    table = CliRunner().invoke(app, ["inspect", str(typed3)], env={"COLUMNS": "200"})
    assert table.exit_code == 0, table.output
    assert "type: Float64[3]" in table.output and "type: Float64[2,3]" in table.output
    assert table.output.count("type: Binary") == 2
    assert "clock tick (input): constant, interval 0.1 s" in table.output
    as_json = CliRunner().invoke(app, ["inspect", str(typed3), "--json"])
    assert as_json.exit_code == 0, as_json.output
    data = json.loads(as_json.output)
    variables = {v["name"]: v for v in data["variables"]}
    assert variables["u"]["dimensions"] == [3] and variables["y"]["dimensions"] == [2, 3]
    assert variables["data_in"]["type"] == variables["data_out"]["type"] == "Binary"
    assert data["clocks"] == ["tick"] and data["scheduled_execution"] is False
    assert variables["tick"]["clock"] == {
        "interval_variability": "constant",
        "interval_s": 0.1,
        "shift_s": None,
        "can_be_deactivated": False,
        "priority": 0,
    }


PAYLOADS = [b"", b"\x00", b"fmu\x00bridge\x00", bytes(range(256)), np.random.default_rng(3).bytes(65_536)]


@pytest.mark.parametrize("payload", PAYLOADS, ids=["empty", "nul", "embedded-nul", "all-bytes", "64KiB"])
def test_binary_is_written_as_bytes_and_read_back_exactly(typed3: Path, payload: bytes) -> None:
    with Model(typed3, step_size_s=STEP_S) as model:
        model.initialize()
        assert model.get(["data_in", "data_out"]) == {"data_in": b"fmu", "data_out": b"umf"}
        model.set({"data_in": payload})
        assert model.get(["data_in"]) == {"data_in": payload}
        model.advance(1)
        values = model.get(["data_in", "data_out", "data_size", "data_sum"])
    assert values["data_in"] == payload and values["data_out"] == payload[::-1]
    assert values["data_size"] == len(payload) and values["data_sum"] == float(sum(payload))


def test_binary_start_value_given_at_initialisation_and_restored_by_reset(typed3: Path) -> None:
    """Restoring an FMU state brings the Binary back: the snapshot copies the bytes, not the pointer."""
    with Model(typed3, step_size_s=STEP_S, reset_policy="restore") as model:
        for episode in range(4):
            model.reset({"data_in": b"\x01\x02\xff"})
            assert model.get(["data_in", "data_out", "ticks"]) == {
                "data_in": b"\x01\x02\xff",
                "data_out": b"\xff\x02\x01",
                "ticks": 0,
            }, f"episode {episode}"
            model.set({"data_in": bytes([episode]) * (episode + 1)})
            model.advance(2)
            assert model.get(["data_out", "ticks"]) == {
                "data_out": bytes([episode]) * (episode + 1),
                "ticks": 2,
            }


def test_binary_and_clock_misuse_is_refused_with_the_reason(typed3: Path) -> None:
    with Model(typed3, step_size_s=STEP_S) as model:
        model.initialize()
        with pytest.raises(VariableError, match=r"'data_in' \(Binary\) expects bytes, got str"):
            model.set({"data_in": "text"})
        with pytest.raises(VariableError, match=r"'tick' \(Clock\).*cannot be set"):
            model.set({"tick": True})
        with pytest.raises(VariableError, match="are clocks: they are listed, not read"):
            model.get(["tick"])
        with pytest.raises(VariableError, match="signal 'data_out' is a Binary variable"):
            model.signals(["data_out"])
        with pytest.raises(VariableError, match=r"'u' is an array of shape \(3,\) \(3 elements\), got 2"):
            model.set({"u": [1.0, 2.0]})


def test_clock_ticks_count_whole_intervals_from_the_start_time(typed3: Path) -> None:
    with Model(typed3, step_size_s=0.25, start_time_s=2.0) as model:
        model.initialize()
        counts = []
        for _ in range(6):
            model.advance(1)
            counts.append(model.get(["ticks"])["ticks"])
    assert counts == [int(0.25 * k / 0.1 + 1e-9) for k in range(1, 7)] == [2, 5, 7, 10, 12, 15]


def _experiment(tmp_path: Path, fmu: Path) -> Path:
    config = tmp_path / "typed3.yaml"
    config.write_text(
        f"model: {{fmu: {q(str(fmu))}, episode_duration: 1.0, step_size: {STEP_S}}}\n"
        'actions: {inputs: ["u[1]", "u[3]"], low: {"u[1]": -2.0, "u[3]": 0.0}, '
        'high: {"u[1]": 2.0, "u[3]": 4.0}}\n'
        'observations: {outputs: ["y[2,3]", "y[1,1]", "y[2,1]", "y[2,2]", "ticks", "data_sum"], '
        "scale: none}\n"
        "reward: {terms: [{alive: 1.0}]}\n"
    )
    return config


def test_array_elements_in_an_experiment_are_flattened_and_match_the_closed_form(
    typed3: Path, tmp_path: Path
) -> None:
    actions = [[0.5, -1.0], [-1.0, 0.25], [1.0, 1.0], [0.0, -0.5]]  # u[1] = 2a, u[3] = 2 + 2a
    with FmuEnv(_experiment(tmp_path, typed3)) as env:
        assert env.action_space.shape == (2,) and env.observation_space.shape == (6,)
        env.reset(seed=0)
        integral = np.zeros(3)
        for k, action in enumerate(actions, start=1):
            obs, *_ = env.step(np.array(action, dtype=np.float32))
            u = np.array([2.0 * action[0], 2.0, 2.0 + 2.0 * action[1]])  # u[2] keeps its start value
            integral += u * STEP_S
            expected = [integral[2], u[0], integral[0], integral[1], k, float(sum(b"fmu"))]
            # same float64 operations as the C code, then the observation space's float32
            np.testing.assert_array_equal(obs, np.asarray(expected, dtype=np.float32))


def test_constant_actions_give_fmpy_simulate_fmu_trajectory(typed3: Path, tmp_path: Path) -> None:
    """The same run through FMPy's own simulate_fmu, with u given as start values."""
    reference = simulate_fmu(
        str(typed3),
        stop_time=0.5,
        output_interval=STEP_S,
        output=["y", "ticks"],
        start_values={"u": np.array([1.0, 2.0, 3.0])},  # the actions 0.5, 0.5 below
    )
    observed = []
    with FmuEnv(_experiment(tmp_path, typed3)) as env:
        env.reset(seed=0)
        for _ in range(5):
            obs, *_ = env.step(np.array([0.5, 0.5], dtype=np.float32))
            observed.append(obs)
    y = reference["y"][1:]
    expected = np.column_stack([y[:, 1, 2], y[:, 0, 0], y[:, 1, 0], y[:, 1, 1], reference["ticks"][1:]])
    np.testing.assert_array_equal(np.array(observed)[:, :5], expected.astype(np.float32))


def test_model_info_reads_typed3_without_problems(typed3: Path) -> None:
    info = read_model_info(typed3)
    assert info.problems == ()
    assert info.variables["y"].element_names()[-1] == "y[2,3]" and info.element("y[2,1]")[1] == 3


def test_fmpy_bindings_get_arrays_flattened_and_a_wrong_count_is_refused(
    typed3: Path, tmp_path: Path
) -> None:
    """FMPy's own FMI 3.0 calls (not bridge.fmu): nValues is the sum of the element counts."""
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(typed3))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    messages: list[str] = []
    slave = FMU3Slave(
        guid=md.guid,
        unzipDirectory=extract(str(typed3), unzipdir=str(tmp_path / "fmu")),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="raw",
    )
    slave.instantiate(logMessage=lambda env, status, category, message: messages.append(message.decode()))
    try:
        slave.enterInitializationMode(startTime=0.0)
        slave.exitInitializationMode()
        slave.setFloat64([vr["u"]], [0.5, -1.0, 4.0])
        slave.doStep(0.0, 0.5)
        assert slave.getFloat64([vr["y"]], nValues=6) == [0.5, -1.0, 4.0, 0.25, -0.5, 2.0]
        assert slave.getFloat64([vr["u"], vr["data_sum"]], nValues=4) == [0.5, -1.0, 4.0, 328.0]
        slave.setBinary([vr["data_in"]], [b""])
        slave.doStep(0.5, 0.5)
        assert slave.getBinary([vr["data_out"]]) == [b""]  # a valid pointer, not NULL
        with pytest.raises(Exception, match="fmi3GetFloat64"):
            slave.getFloat64([vr["y"]], nValues=5)
        assert any("expected 6 values" in m and "got 5" in m for m in messages), messages
    finally:
        slave.freeInstance()
