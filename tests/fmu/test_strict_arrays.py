"""FMI 3.0 arrays on every path, against a model that refuses anything but whole-array calls.

``strict_arrays`` (bridge/models/strict.py) answers a get or set whose ``nValues`` is not the
sum of the element counts of its value references with fmi3Error, like a strict exporter. With
``u`` held at ``u_i = i`` (the mid-point of each action's range), ``k = 1`` and ``x_i(0) = 0.5 i``,
its state is ``x_i(t) = i (1 - 0.5 exp(-t))`` and ``der(x)_i = 0.5 i exp(-t)``; ``y`` is
``[x; der(x)]`` (2 x n, row-major) and ``total`` the sum of ``x``. Every path is compared with
that closed form and with FMPy's ``simulate_fmu``: the single env over the native one-call
sample and over the Python calls, model exchange (CVode and the native fixed-step batch), the
batch env, a system of two such FMUs (native and Python master) and a node over loopback Zenoh.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.batch import BatchEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import FmuError, VariableError
from bridge.experiment.config import parse_experiment
from bridge.fmu import Model
from bridge.fmu.sample import NativeSample
from bridge.models.strict import strict_arrays_fmu
from bridge.plant.system.plant import SystemPlant

N = 3
H = 0.1
STEPS = 20
U = [f"u[{i}]" for i in range(1, N + 1)]
Y = [f"y[{r},{i}]" for r in (1, 2) for i in range(1, N + 1)]
OUTPUTS = [*Y, "total"]


@pytest.fixture(scope="module")
def fmu() -> Path:
    return strict_arrays_fmu()


def closed_form(t: np.ndarray, n: int = N) -> np.ndarray:
    """Rows of ``y[1,1..n], y[2,1..n], total`` at the times ``t`` (u_i = i, k = 1, x_i(0) = 0.5 i)."""
    i = np.arange(1, n + 1, dtype=np.float64)
    e = np.exp(-np.asarray(t, dtype=np.float64))[:, None]
    x = i * (1.0 - 0.5 * e)
    return np.hstack([x, 0.5 * i * e, x.sum(axis=1, keepdims=True)])


def fmpy_rows(fmu: Path, fmi_type: str) -> np.ndarray:
    from fmpy import simulate_fmu

    result = simulate_fmu(
        str(fmu), fmi_type=fmi_type, stop_time=STEPS * H, output_interval=H, output=["y", "total"]
    )
    y = np.asarray(result["y"], dtype=np.float64).reshape(len(result), -1)  # row-major, as FMI 3.0
    return np.hstack([y, np.asarray(result["total"], dtype=np.float64)[:, None]])


def experiment(fmu: Path, tmp_path: Path, **model: Any) -> dict[str, Any]:
    data = {
        "model": {"fmu": str(fmu), "step_size": H, "sampling_time": H, "episode_duration": 3.0, **model},
        "actions": {
            "inputs": U,
            "low": dict.fromkeys(U, 0.0),
            "high": {name: 2.0 * i for i, name in enumerate(U, start=1)},
        },
        "observations": {"outputs": OUTPUTS},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    (tmp_path / "strict.yaml").write_text(yaml.safe_dump(data))
    return data


def episode(env: Any) -> np.ndarray:
    obs, _ = env.reset(seed=0)
    rows = [obs]
    for _ in range(STEPS):
        obs, *_ = env.step(np.zeros(N, dtype=np.float32))  # the mid-point: u_i = i exactly
        rows.append(obs)
    return np.asarray(rows, dtype=np.float64)


@contextlib.contextmanager
def native_off(monkeypatch: pytest.MonkeyPatch, off: bool) -> Iterator[None]:
    with monkeypatch.context() as patch:
        if off:
            patch.setenv("FMU_BRIDGE_NO_NATIVE", "1")
        else:
            patch.delenv("FMU_BRIDGE_NO_NATIVE", raising=False)
        yield


TIMES = np.arange(STEPS + 1) * H


@pytest.mark.parametrize("python", [False, True], ids=["native-sample", "python-calls"])
def test_single_env_co_simulation_equals_closed_form_and_fmpy(
    fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, python: bool
) -> None:
    exp = parse_experiment(experiment(fmu, tmp_path, interface="cs"), source=tmp_path / "strict.yaml")
    with native_off(monkeypatch, python), FmuEnv(exp) as env:
        rows = episode(env)
        assert env.unwrapped.plant.native_stepping != python  # type: ignore[attr-defined]
    np.testing.assert_allclose(rows, closed_form(TIMES), rtol=1e-6, atol=1e-7)  # float32 observations
    np.testing.assert_allclose(rows, fmpy_rows(fmu, "CoSimulation"), rtol=1e-6, atol=1e-7)


def test_model_exchange_env_equals_closed_form_and_fmpy(fmu: Path, tmp_path: Path) -> None:
    exp = parse_experiment(experiment(fmu, tmp_path, interface="me"), source=tmp_path / "strict.yaml")
    with FmuEnv(exp) as env:
        rows = episode(env)
    np.testing.assert_allclose(rows, closed_form(TIMES), rtol=2e-5, atol=2e-5)
    np.testing.assert_allclose(rows, fmpy_rows(fmu, "ModelExchange"), rtol=2e-4, atol=2e-4)  # CVode vs CVode


@pytest.mark.parametrize(
    "model",
    [{"interface": "cs"}, {"interface": "me", "solver": "rk4", "solver_substeps": 4}],
    ids=["cs", "me-rk4"],
)
@pytest.mark.parametrize("native", [True, False], ids=["native", "python"])
def test_batch_env_equals_closed_form(fmu: Path, tmp_path: Path, model: dict[str, Any], native: bool) -> None:
    exp = parse_experiment(experiment(fmu, tmp_path, **model), source=tmp_path / "strict.yaml")
    env = BatchEnv(exp, 3, native=native)
    try:
        obs = env.reset_all([0, 1, 2])[0]
        rows = [obs]
        for _ in range(STEPS):
            obs = env.step(np.zeros((3, N), dtype=np.float32))[0]
            rows.append(obs)
        assert env.plant.batch.native == native  # type: ignore[attr-defined]
    finally:
        env.close()
    every = np.asarray(rows, dtype=np.float64)  # (time, env, signal)
    rtol = 1e-6 if model["interface"] == "cs" else 1e-5  # RK4, four substeps a step
    for i in range(3):
        np.testing.assert_allclose(every[:, i], closed_form(TIMES), rtol=rtol, atol=rtol)
    np.testing.assert_allclose(every[:, 0], fmpy_rows(fmu, "CoSimulation"), rtol=rtol, atol=rtol)


def system_data(fmu: Path) -> dict[str, Any]:
    """``a`` drives ``b``: ``a.y[1,j] -> b.u[j]`` (a's state is b's input), the agent drives ``a.u``."""
    a_inputs = [f"a.{name}" for name in U]
    data = {
        "system": {
            "components": {"a": {"fmu": str(fmu)}, "b": {"fmu": str(fmu)}},
            "connections": [f"a.y[1,{j}] -> b.u[{j}]" for j in range(1, N + 1)],
        },
        "model": {"step_size": H, "sampling_time": H, "episode_duration": 3.0},
        "actions": {
            "inputs": a_inputs,
            "low": dict.fromkeys(a_inputs, 0.0),
            "high": {name: 2.0 * i for i, name in enumerate(a_inputs, start=1)},
        },
        "observations": {"outputs": [*(f"a.{y}" for y in Y), *(f"b.{y}" for y in Y)]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    return data


def system(fmu: Path, tmp_path: Path) -> Any:
    return parse_experiment(system_data(fmu), source=tmp_path / "system.yaml")


def system_closed_form() -> np.ndarray:
    """Jacobi with held inputs: b's input over [t_k, t_k+1] is a's x at t_k; each step exact."""
    i = np.arange(1, N + 1, dtype=np.float64)
    decay = np.exp(-H)
    a_x = i * (1.0 - 0.5 * np.exp(-TIMES))[:, None]
    b_x = [0.5 * i]
    for k in range(STEPS):
        b_x.append(a_x[k] + (b_x[-1] - a_x[k]) * decay)
    b = np.asarray(b_x)
    a_u = np.broadcast_to(i, a_x.shape)
    b_u = np.vstack([a_x[:1], a_x[:-1]])  # b.u at t_k: a.x at t_k-1 (at t0: the start iteration's a.x(t0))
    return np.hstack([a_x, a_u - a_x, b, b_u - b])


@pytest.mark.parametrize("python_master", [False, True], ids=["native-master", "python-master"])
def test_system_of_two_array_models_equals_closed_form(
    fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, python_master: bool
) -> None:
    if python_master:
        monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    exp = system(fmu, tmp_path)
    names = [*(f"a.{y}" for y in Y), *(f"b.{y}" for y in Y)]
    plant = SystemPlant(exp)
    with plant:
        plant.bind([f"a.{u}" for u in U], names)
        rows = [plant.reset({}, [1.0, 2.0, 3.0])]
        rows += [plant.step([1.0, 2.0, 3.0]) for _ in range(STEPS)]
        assert (plant.master.native is not None) != python_master
    np.testing.assert_allclose(np.asarray(rows)[1:], system_closed_form()[1:], rtol=1e-12, atol=1e-12)


def test_a_node_holds_each_input_element_at_its_array_start_value(fmu: Path) -> None:
    """What a node holds its inputs at before an action and sends at a ROS reset: an element's
    start is its entry of the array's start (``u``'s is "1 2 3"), as the env's task reads it,
    not 0 (the node read only a parsed list)."""
    from bridge.experiment.validate import with_elements
    from bridge.fmu import read_model_info
    from bridge.net.served import element_start

    info = read_model_info(fmu)
    assert [element_start(info, name) for name in U] == [1.0, 2.0, 3.0]
    assert [with_elements(info.variables)[name].start for name in U] == [1.0, 2.0, 3.0]


@pytest.mark.integration
def test_node_over_loopback_zenoh_equals_the_single_env(fmu: Path, tmp_path: Path, loopback: Any) -> None:
    from bridge.env import RemoteFmuEnv
    from tests.conftest import node_process

    experiment(fmu, tmp_path, interface="cs")
    path = tmp_path / "strict.yaml"
    with node_process(path, "arrays", loopback):
        remote = RemoteFmuEnv(path, "arrays", session=loopback.session, prefix=loopback.prefix)
        try:
            rows = episode(remote)
        finally:
            remote.close()
    with FmuEnv(path) as local:
        np.testing.assert_array_equal(rows, episode(local))
    np.testing.assert_allclose(rows, fmpy_rows(fmu, "CoSimulation"), rtol=1e-6, atol=1e-7)


def test_the_model_refuses_element_wise_calls(fmu: Path) -> None:
    """The model is as strict as the issue's exporter: one element of an array is an error."""
    with Model(fmu) as model:
        model.initialize()
        with pytest.raises(FmuError, match=r"Expected nValues = 3 but was 1"):
            model.backend.call("an element-wise set", lambda: model.backend.fmu.setFloat64([3], [1.0]))
        native = NativeSample.create(model, model.signals(U, writable=True), model.signals(OUTPUTS), 1)
        assert native is not None  # whole arrays in row-major order: the one-call sample serves them
        np.testing.assert_allclose(native([1.0, 2.0, 3.0]), closed_form(TIMES[1:2])[0], rtol=1e-12)


def test_some_elements_of_an_input_array_keep_the_others(fmu: Path) -> None:
    """Writing u[2] alone reads u, changes u[2] and writes the whole array back."""
    with Model(fmu) as model:
        model.initialize()
        group = model.signals(["u[2]"], writable=True, role="input")
        group.write([7.0])
        np.testing.assert_array_equal(model.get(["u"])["u"], [1.0, 7.0, 3.0])
        model.set({"u[3]": 9.0})
        np.testing.assert_array_equal(model.get(["u"])["u"], [1.0, 7.0, 9.0])
        with pytest.raises(VariableError, match="3 elements"):
            model.set({"u": [1.0, 2.0]})


@pytest.mark.integration
def test_system_with_an_array_component_in_a_node_equals_closed_form(
    fmu: Path, tmp_path: Path, loopback: Any
) -> None:
    """``b`` served by ``fmu-bridge system serve``: its array input and 2-D output cross the wire
    element by element (``u[1]``..., ``y[1,1]``...) and it calls the FMU with whole arrays."""
    from bridge.experiment.config import load_experiment
    from bridge.net.system_node import NodeComponents
    from tests.plant.test_system_nodes import serve

    data = system_data(fmu)
    data["system"]["components"]["b"]["node"] = "b-arrays"
    path = tmp_path / "nodes.yaml"
    path.write_text(yaml.safe_dump(data))
    names = [*(f"a.{y}" for y in Y), *(f"b.{y}" for y in Y)]
    with serve(path, loopback, "b"):
        remote = NodeComponents(session=loopback.session, prefix=loopback.prefix, timeout_s=60.0)
        plant = SystemPlant(load_experiment(path), remote=remote)
        with plant:
            assert type(plant.plants["b"]).__name__ == "RemotePlant"
            plant.bind([f"a.{u}" for u in U], names)
            rows = [plant.reset({}, [1.0, 2.0, 3.0])]
            rows += [plant.step([1.0, 2.0, 3.0]) for _ in range(STEPS)]
    np.testing.assert_allclose(np.asarray(rows)[1:], system_closed_form()[1:], rtol=1e-12, atol=1e-12)


# -- structural parameters -----------------------------------------------------------------------


def sized_experiment(fmu: Path, tmp_path: Path, n: int, **model: Any) -> dict[str, Any]:
    inputs = [f"u[{i}]" for i in range(1, n + 1)]
    outputs = [f"y[{r},{i}]" for r in (1, 2) for i in range(1, n + 1)] + ["total"]
    data = {
        "model": {
            "fmu": str(fmu),
            "step_size": H,
            "sampling_time": H,
            "episode_duration": 3.0,
            "structural_parameters": {"n": n},
            **model,
        },
        "actions": {
            "inputs": inputs,
            "low": dict.fromkeys(inputs, 0.0),
            "high": {name: 2.0 * i for i, name in enumerate(inputs, start=1)},
        },
        "observations": {"outputs": outputs},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    (tmp_path / "sized.yaml").write_text(yaml.safe_dump(data))
    return data


def sized_episode(env: Any, n: int) -> np.ndarray:
    obs, _ = env.reset(seed=0)
    rows = [obs]
    for _ in range(STEPS):
        rows.append(env.step(np.zeros(n, dtype=np.float32))[0])
    return np.asarray(rows, dtype=np.float64)


def test_a_structural_parameter_sizes_the_arrays_in_configuration_mode(fmu: Path) -> None:
    with Model(fmu, structural_parameters={"n": 5}, reset_policy="reset") as model:
        assert model.info.variables["y"].dimensions == (2, 5) and model.info.number_of_states == 5
        model.initialize()
        u = model.signals([f"u[{i}]" for i in range(1, 6)], writable=True)
        y = model.signals([*model.info.variables["y"].element_names(), "total"])
        native = NativeSample.create(model, u, y, 1)
        assert native is not None
        for _ in range(2):  # an fmi reset returns n to its start: the model configures it again
            model.reset()
            native.refresh()
            np.testing.assert_allclose(
                native([1.0, 2.0, 3.0, 4.0, 5.0]), closed_form(TIMES[1:2], 5)[0], rtol=1e-12
            )
    with Model(fmu) as default:
        assert default.info.variables["u"].dimensions == (3,)  # the start value of n


@pytest.mark.parametrize(
    ("interface", "isolation"),
    [("cs", None), ("me", None), ("cs", {"timeout": 60.0})],
    ids=["cs", "me", "isolated"],
)
def test_structural_parameters_from_the_experiment_on_the_env(
    fmu: Path, tmp_path: Path, interface: str, isolation: dict[str, float] | None
) -> None:
    model: dict[str, Any] = {"interface": interface, **({"isolation": isolation} if isolation else {})}
    exp = parse_experiment(sized_experiment(fmu, tmp_path, 5, **model), source=tmp_path / "x.yaml")
    with FmuEnv(exp) as env:
        assert env.unwrapped.plant.isolated == (isolation is not None)  # type: ignore[attr-defined]
        assert env.observation_space.shape == (11,)
        rows = sized_episode(env, 5)
    tolerance = 1e-6 if interface == "cs" else 2e-5
    expected = closed_form(TIMES, 5)
    # at t0 the inputs hold 0: the declared start (3 values) does not apply to 5 elements
    np.testing.assert_allclose(rows[0, 5:10], -expected[0, :5], rtol=1e-7)
    np.testing.assert_allclose(rows[1:], expected[1:], rtol=tolerance, atol=tolerance)
    np.testing.assert_allclose(rows[0, :5], expected[0, :5], rtol=1e-7)


@pytest.mark.integration
def test_structural_parameters_on_the_batch_env_and_a_node(fmu: Path, tmp_path: Path, loopback: Any) -> None:
    from bridge.env import RemoteFmuEnv
    from tests.conftest import node_process

    sized_experiment(fmu, tmp_path, 4)
    path = tmp_path / "sized.yaml"
    env = BatchEnv(path, 2, native=True)
    try:
        rows = [env.reset_all([0, 1])[0]]
        rows += [env.step(np.zeros((2, 4), dtype=np.float32))[0] for _ in range(STEPS)]
    finally:
        env.close()
    every = np.asarray(rows, dtype=np.float64)
    for i in range(2):  # from the first step on: at t0 the inputs hold 0 (no start for 4 elements)
        np.testing.assert_allclose(every[1:, i], closed_form(TIMES, 4)[1:], rtol=1e-6, atol=1e-6)
    with node_process(path, "sized", loopback):
        remote = RemoteFmuEnv(path, "sized", session=loopback.session, prefix=loopback.prefix)
        try:
            np.testing.assert_array_equal(sized_episode(remote, 4), every[:, 0].astype(np.float32))
        finally:
            remote.close()


def test_structural_parameters_refused_where_they_do_not_belong(fmu: Path, tmp_path: Path) -> None:
    from bridge.errors import ConfigError

    with pytest.raises(
        ConfigError, match=r"'k' of strict_arrays is a fixed parameter.*structural parameters.*\['n'\]"
    ):
        Model(fmu, structural_parameters={"k": 2})
    with (
        Model(fmu) as model,
        pytest.raises(VariableError, match=r"'n' .* structural parameter .* configuration mode"),
    ):
        model.initialize({"n": 5})  # not in initialisation mode, where the model would refuse it
    data = sized_experiment(fmu, tmp_path, 5)
    data["model"]["parameters"] = {"n": 5}
    with pytest.raises(
        ConfigError, match=r"model.parameters: 'n' is a structural parameter.*model.structural_parameters"
    ):
        FmuEnv(parse_experiment(data, source=tmp_path / "x.yaml"))
    data["model"]["parameters"] = {}
    data["model"]["structural_parameters"] = {}  # u[5] does not exist at the default size 3
    with pytest.raises(ConfigError, match=r"u\[4\]"):
        FmuEnv(parse_experiment(data, source=tmp_path / "x.yaml"))


@pytest.mark.integration
@pytest.mark.parametrize("node", [False, True], ids=["in-process", "node"])
def test_structural_parameters_of_a_system_component(
    fmu: Path, tmp_path: Path, loopback: Any, node: bool
) -> None:
    """``b`` at n = 4: ``a.y[1,j] -> b.u[j]`` for j <= 3; ``b.u[4]`` keeps its value from the FMU
    (configuration sets u_i = i; no one writes it), so ``x_4`` of ``b`` follows the closed form."""
    from bridge.experiment.config import load_experiment
    from bridge.net.system_node import NodeComponents
    from tests.plant.test_system_nodes import serve

    data = system_data(fmu)
    data["system"]["components"]["b"]["structural_parameters"] = {"n": 4}
    if node:
        data["system"]["components"]["b"]["node"] = "b-sized"
    data["observations"]["outputs"] = [f"b.y[1,{j}]" for j in range(1, 5)]
    path = tmp_path / "sized_system.yaml"
    path.write_text(yaml.safe_dump(data))
    names = data["observations"]["outputs"]
    remote = (
        NodeComponents(session=loopback.session, prefix=loopback.prefix, timeout_s=60.0) if node else None
    )
    with serve(path, loopback, "b") if node else contextlib.nullcontext():
        plant = SystemPlant(load_experiment(path), remote=remote)
        with plant:
            plant.bind([f"a.{u}" for u in U], names)
            rows = [plant.reset({}, [1.0, 2.0, 3.0])]
            rows += [plant.step([1.0, 2.0, 3.0]) for _ in range(STEPS)]
    got = np.asarray(rows)
    np.testing.assert_allclose(got[1:, :3], system_closed_form()[1:, 2 * N : 3 * N], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[:, 3], closed_form(TIMES, 4)[:, 3], rtol=1e-12)  # u_4 = 4 held
