"""The conformance matrix: every model setting on every path, held to the in-process ``FmuEnv``.

Two tables: :data:`SETTINGS` (a model description: FMU, ``model:`` keys, the signals it is
driven and read by) and :data:`PATHS` (a way of running it). For every cell the path runs two
episodes of a fixed action sequence and its observations must equal ``FmuEnv``'s in this
process bit for bit, or the path refuses with a :class:`ConfigError` naming the setting. A
setting or a path added to a table is tested everywhere at once. In-process paths are the fast
tier; paths that start processes are ``integration``. Each episode is exactly the action sequence
long (``episode_duration``), so paths that run whole episodes (``evaluate``, whose agents and a
deployed agent load the sequence as the experiment's baseline ``sequence``: sequence_policy.py)
run the same ones, and every path must end them exactly there.

The strict models (bridge/models/strict.py) misbehave as real exporters do: ``strict_reset``
keeps its terminated flag through fmi reset and refuses state functions once reset;
``strict_arrays`` refuses element-wise calls.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.batch import BatchEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError, TransportError
from bridge.experiment.config import Experiment, parse_experiment
from bridge.models.clocked import clocks_fmu
from bridge.models.strict import strict_arrays_fmu, strict_reset_fmu
from tests.conformance.sequence_policy import CALLABLE, SEQUENCE, action_row
from tests.conftest import example_fmu

STEPS = 6  # samples per episode: within every model's own episode (strict_reset stops after 10)
EPISODES = (0, 1)  # seeds of the two episodes


@dataclass(frozen=True)
class Setting:
    """A model description under test: its FMU, its ``model:`` keys, and the signals."""

    fmu: Callable[[], Path]
    model: dict[str, Any]
    inputs: list[str]
    outputs: list[str]
    step_size: float = 0.1
    high: float = 2.0
    keys: tuple[str, ...] = ()  # the settings a path may refuse (named in its error)
    prepare: Callable[[Path], dict[str, Any]] | None = None  # more model keys, made in tmp_path


def _arrays() -> Path:
    return strict_arrays_fmu()


def _reset() -> Path:
    return strict_reset_fmu()


def _slow_init() -> Path:
    return example_fmu("slow_init", "2.0", "cs")


def _saved_state(tmp_path: Path) -> dict[str, Any]:
    """A state file of slow_init after 20 steps from ambient: every episode starts there."""
    from bridge.fmu import Model, state_file

    path = tmp_path / "warm.state"
    with Model(_slow_init(), step_size_s=0.05) as model:
        model.initialize({"warmup_steps": 0})
        for k in range(20):
            model.set({"power": 10.0 + k})
            model.advance(1)
        state_file.write(path, model.state_file())
    return {"reset_policy": {"state_file": str(path)}}


def _cartpole(version: str, interface: str) -> Callable[[], Path]:
    return lambda: example_fmu("cartpole", version, interface)


def _clocks(interface: str) -> Callable[[], Path]:
    return lambda: clocks_fmu(interface)


# high 4: a node refuses reset inputs outside the action range, and u's start (u[3] = 3) is one
ARRAY_SIGNALS: dict[str, Any] = {
    "inputs": ["u[1]", "u[3]"],
    "outputs": ["total", "y[1,2]", "y[2,3]", "det_A"],
    "high": 4.0,
}
CART: dict[str, Any] = {
    "inputs": ["force"],
    "outputs": ["x", "theta", "theta_dot"],
    "step_size": 0.02,
    "high": 5.0,
}

# clocks3 (bridge/models/clocked.py, docs/clocks.md): the agent drives r and ticks the triggered
# clock (above 0.5); c_fixed at 0.05 + 0.2 k (not the FMU's 0.25), trigger also at the schedule's
# times. 0.06 s samples: no tick of these falls on a sample time.
CLOCKS: dict[str, Any] = {
    "inputs": ["r", "trigger"],
    "outputs": ["x", "u", "n_fixed", "n_trigger", "n_const", "n_out", "n_countdown"],
    "step_size": 0.06,
    "high": 1.0,
    "keys": ("clock_intervals", "clock_schedule"),
}
CLOCK_SETTINGS: dict[str, Any] = {
    "clock_intervals": {"c_fixed": 0.2},
    "clock_schedule": {"trigger": [0.1, 0.25]},
}

SETTINGS: dict[str, Setting] = {
    "fmi3-cs-parameters": Setting(_arrays, {"interface": "cs", "parameters": {"k": 0.5}}, **ARRAY_SIGNALS),
    "fmi3-array-element-parameters": Setting(
        _arrays, {"parameters": {"A[1,1]": 2.0, "A[2,1]": 3.0}}, **ARRAY_SIGNALS, keys=("parameters",)
    ),
    "fmi3-start-values": Setting(_arrays, {"start_values": {"x[2]": 4.0}}, **ARRAY_SIGNALS),
    "fmi3-structural-parameters": Setting(
        _arrays, {"structural_parameters": {"n": 4}}, **ARRAY_SIGNALS, keys=("structural_parameters",)
    ),
    "fmi3-me-cvode-tolerance": Setting(
        _arrays, {"interface": "me", "tolerance": 1e-8}, **ARRAY_SIGNALS, keys=("interface", "tolerance")
    ),
    "fmi3-me-rk4-substeps": Setting(
        _arrays,
        {"interface": "me", "solver": "rk4", "solver_substeps": 3},
        **ARRAY_SIGNALS,
        keys=("solver",),
    ),
    **{
        f"fmi2-reset-{policy}": Setting(
            _reset, {"reset_policy": policy}, ["u"], ["x"], keys=("reset_policy",)
        )
        for policy in ("auto", "restore", "reinstantiate", "reset")
    },
    "fmi2-state-file": Setting(
        _slow_init,
        {"parameters": {"warmup_steps": 0}},
        ["power"],
        ["T"],
        step_size=0.05,
        high=20.0,
        # a plain node refuses a sent state (it deserialises states only in an isolated child)
        keys=("state_file", "state file"),
        prepare=_saved_state,
    ),
    "fmi2-cs": Setting(_cartpole("2.0", "cs"), {"parameters": {"theta0": 0.05}}, **CART),
    "fmi2-me": Setting(_cartpole("2.0", "me"), {"interface": "me"}, **CART, keys=("interface",)),
    "fmi1-cs": Setting(_cartpole("1.0", "cs"), {"parameters": {"theta0": 0.05}}, **CART, keys=("fmu",)),
    "fmi3-cs-cartpole": Setting(_cartpole("3.0", "cs"), {"start_values": {"theta0": 0.1}}, **CART),
    "fmi3-cs-clocks": Setting(_clocks("cs"), {"interface": "cs", **CLOCK_SETTINGS}, **CLOCKS),
    "fmi3-me-clocks": Setting(_clocks("me"), {"interface": "me", **CLOCK_SETTINGS}, **CLOCKS),
    # scheduled execution: chosen explicitly, and as the only interface the FMU offers
    "fmi3-se": Setting(_clocks("se"), {"interface": "se", **CLOCK_SETTINGS}, **CLOCKS),
    "fmi3-se-auto": Setting(_clocks("se"), {"interface": "auto", **CLOCK_SETTINGS}, **CLOCKS),
}


def experiment(setting: Setting, tmp_path: Path, **model: Any) -> dict[str, Any]:
    inputs = setting.inputs
    return {
        "model": {
            "fmu": str(setting.fmu()),
            "step_size": setting.step_size,
            "sampling_time": setting.step_size,
            "episode_duration": STEPS * setting.step_size,  # evaluate and agents run whole episodes
            **setting.model,
            **(setting.prepare(tmp_path) if setting.prepare else {}),
            **model,
        },
        "actions": {
            "inputs": inputs,
            "low": dict.fromkeys(inputs, 0.0),
            "high": dict.fromkeys(inputs, setting.high),
        },
        "observations": {"outputs": setting.outputs, "scale": "none"},
        "reward": {"terms": [{"alive": 1.0}]},
    }


def actions(setting: Setting) -> np.ndarray:
    """A fixed action sequence in [-1, 1] that moves every input (the agent paths' sequence too)."""
    return np.array([action_row(k, len(setting.inputs)) for k in range(STEPS)])


def with_sequence(data: dict[str, Any]) -> dict[str, Any]:
    """The experiment with the fixed sequence as its baseline ``sequence`` (what agents load)."""
    baseline = {"type": "python", "callable": CALLABLE}
    return {**data, "evaluation": {"baselines": {"sequence": baseline}}}


def run_env(env: Any, setting: Setting) -> np.ndarray:
    rows = []
    for seed in EPISODES:
        obs, _ = env.reset(seed=seed)
        rows.append(obs)
        for k, action in enumerate(actions(setting)):
            obs, _, terminated, truncated, _ = env.step(action)
            rows.append(obs)
            assert (terminated, truncated) == (False, k == STEPS - 1), f"episode {seed} ended at {k}"
    return np.asarray(rows, dtype=np.float64)


def run_batch(exp: Experiment, setting: Setting, n: int) -> np.ndarray:
    env = BatchEnv(exp, n, autoreset=False)  # the last observation of each episode, not the next reset
    try:
        rows = []
        for seed in EPISODES:
            obs = env.reset_all([seed] * n)[0]
            rows.append(obs)
            for k, action in enumerate(actions(setting)):
                obs, _, terminated, truncated, _ = env.step(np.repeat(action[None, :], n, axis=0))
                rows.append(obs.copy())  # the env's own buffer, written again at the next call
                assert not np.any(terminated) and np.all(truncated == (k == STEPS - 1)), (seed, k)
    finally:
        env.close()
    every = np.asarray(rows, dtype=np.float64)  # (time, env, signal)
    for i in range(1, n):
        np.testing.assert_array_equal(every[:, i], every[:, 0])  # the instances agree
    return every[:, 0]


def in_process(setting: Setting, tmp_path: Path) -> np.ndarray:
    exp = parse_experiment(experiment(setting, tmp_path), source=tmp_path / "e.yaml")
    with FmuEnv(exp) as env:
        rows = run_env(env, setting)
    return rows


def isolated(setting: Setting, tmp_path: Path, net: Any) -> np.ndarray:
    data = experiment(setting, tmp_path, isolation={"timeout": 60.0})
    with FmuEnv(parse_experiment(data, source=tmp_path / "e.yaml")) as env:
        assert env.unwrapped.plant.isolated  # type: ignore[attr-defined]
        rows = run_env(env, setting)
    return rows


def batch_of(n: int) -> Callable[[Setting, Path], np.ndarray]:
    def run(setting: Setting, tmp_path: Path) -> np.ndarray:
        exp = parse_experiment(experiment(setting, tmp_path), source=tmp_path / "e.yaml")
        return run_batch(exp, setting, n)

    return run


def as_component(setting: Setting, tmp_path: Path) -> dict[str, Any]:
    """The model as the one component ``a`` of a system, its settings under system.components.a."""
    data = experiment(setting, tmp_path)
    model = data["model"]
    component = {k: v for k, v in model.items() if k not in ("sampling_time", "episode_duration")}
    data["model"] = {k: model[k] for k in ("step_size", "sampling_time", "episode_duration")}
    data["system"] = {"components": {"a": component}, "connections": []}
    data["actions"] = {
        "inputs": [f"a.{n}" for n in setting.inputs],
        "low": {f"a.{n}": 0.0 for n in setting.inputs},
        "high": {f"a.{n}": setting.high for n in setting.inputs},
    }
    data["observations"] = {"outputs": [f"a.{n}" for n in setting.outputs], "scale": "none"}
    return data


def system_component(setting: Setting, tmp_path: Path) -> np.ndarray:
    data = as_component(setting, tmp_path)
    with FmuEnv(parse_experiment(data, source=tmp_path / "s.yaml")) as env:
        rows = run_env(env, setting)
    return rows


def node(setting: Setting, tmp_path: Path, net: Any, *flags: str) -> np.ndarray:
    """``fmu-bridge node`` serving the experiment, driven by RemoteFmuEnv over loopback Zenoh."""
    from bridge.env import RemoteFmuEnv
    from tests.conftest import node_process

    path = tmp_path / "node.yaml"
    path.write_text(yaml.safe_dump(experiment(setting, tmp_path)))
    with node_process(path, "matrix", net, *flags):
        remote = RemoteFmuEnv(path, "matrix", session=net.session, prefix=net.prefix, timeout_s=60.0)
        try:
            return run_env(remote, setting)
        finally:
            remote.close()


def isolated_node(setting: Setting, tmp_path: Path, net: Any) -> np.ndarray:
    """``fmu-bridge node --isolate``: the node's FMU in a child process of the node."""
    return node(setting, tmp_path, net, "--isolate")


def component_in_node(setting: Setting, tmp_path: Path, net: Any) -> np.ndarray:
    """The component ``a`` served by ``fmu-bridge system serve``, the system stepped here."""
    from bridge.net.system_node import NodeComponents
    from bridge.plant.system.plant import SystemPlant
    from tests.plant.test_system_nodes import serve

    data = as_component(setting, tmp_path)
    data["system"]["components"]["a"]["node"] = "a-matrix"
    path = tmp_path / "nodes.yaml"
    path.write_text(yaml.safe_dump(data))
    exp = parse_experiment(data, source=path)
    with serve(path, net, "a"):
        remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)
        with FmuEnv(exp, plant=SystemPlant(exp, remote=remote)) as env:
            rows = run_env(env, setting)
    return rows


def deployed_agent(setting: Setting, tmp_path: Path) -> np.ndarray:
    """A deployed agent (``fmu-bridge agent run sequence --runtime baseline``) on the outputs of
    the plant a node of the experiment runs, reset as a node resets it (its nominal values, the
    inputs' start values) and stepped with the inputs the agent publishes. The observations are
    the ones the agent's Task computed (what its policy was given)."""
    from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
    from agents.policies import load_policy
    from bridge.net.served import element_start
    from bridge.plant.factory import fmu_plant
    from bridge.serving.experiment import experiment_served

    path = tmp_path / "agent.yaml"
    path.write_text(yaml.safe_dump(with_sequence(experiment(setting, tmp_path))))
    exp, _ = deployment_experiment(tmp_path, path)
    spec, served = experiment_served(exp)  # what a node of this experiment runs and serves
    published: list[list[float]] = []
    agent = DeployedAgent(
        load_policy(Path("sequence"), "baseline", exp),
        exp,
        model_info_for(exp, tmp_path, None),
        DeploySettings(runtime="baseline", timeout_s=600.0),
        lambda inputs, step: published.append(inputs),
    )
    assert served.output_names == agent.task.output_names  # as AgentNode checks a node's
    SEQUENCE.episodes.clear()
    plant = fmu_plant(spec)
    try:
        plant.bind(served.input_names, served.output_names)
        starts = [element_start(plant.info, name) for name in served.input_names]
        for episode in EPISODES:
            outputs = plant.reset(dict(served.nominal), starts)
            for k in range(STEPS + 1):
                inputs = agent.observe(outputs.tolist(), episode=episode, step=k)
                if k < STEPS:
                    outputs = plant.step(inputs)
    finally:
        agent.close()
        plant.close()
    assert len(published) == len(EPISODES) * (STEPS + 1)
    return np.concatenate(SEQUENCE.episodes)


def deployed_agent_on_node(setting: Setting, tmp_path: Path, net: Any) -> np.ndarray:
    """``fmu-bridge agent run sequence --runtime baseline`` (:class:`AgentNode`) against
    ``fmu-bridge node --mode lockstep`` over loopback Zenoh: each episode started by a reset
    request with the node's nominal values and the inputs' start values (what a ROS ``~/reset``
    sends), then stepped by the agent's actions alone. A lockstep node steps as long as actions
    come, so the agent holds its answer to an episode's last observation until the next reset
    has been answered; that answer, for the old episode, is then refused by the node."""
    from agents.deploy import DeploySettings
    from agents.deploy_io import AgentNode
    from bridge.net import protocol as proto
    from bridge.net.served import element_start
    from bridge.plant.factory import model_info_for
    from bridge.serving.experiment import experiment_served
    from tests.conftest import node_process, wait_until

    path = tmp_path / "deployed.yaml"
    path.write_text(yaml.safe_dump(with_sequence(experiment(setting, tmp_path))))
    served = experiment_served(parse_experiment(yaml.safe_load(path.read_text()), source=path))[1]
    info = model_info_for(parse_experiment(yaml.safe_load(path.read_text()), source=path))
    starts = [element_start(info, name) for name in served.input_names]
    SEQUENCE.episodes.clear()
    SEQUENCE.hold_after, SEQUENCE.held, SEQUENCE.release = STEPS + 1, threading.Event(), threading.Event()
    settings = DeploySettings(node="matrix", prefix=net.prefix, timeout_s=60.0, runtime="baseline")
    with node_process(path, "matrix", net, "--mode", "lockstep"):
        agent = AgentNode(Path("sequence"), path, settings, session=net.session)
        try:
            for n, _ in enumerate(EPISODES, start=1):
                SEQUENCE.held.clear()
                request = proto.encode_json({"episode": n, "values": {}, "inputs": starts})
                for _reply in net.session.get(proto.Keys(net.prefix, "matrix").reset, payload=request):
                    pass
                if n > 1:
                    SEQUENCE.release.set()  # the last episode's held answer: now for an old episode
                wait_until(SEQUENCE.held.is_set, 60.0, f"episode {n}'s {STEPS + 1} observations")
        finally:
            SEQUENCE.hold_after = None
            SEQUENCE.release.set()
            agent.close()
    assert [len(e) for e in SEQUENCE.episodes] == [STEPS + 1] * len(EPISODES)
    return np.concatenate(SEQUENCE.episodes)


def recorded_observations(path: Path) -> list[np.ndarray]:
    """``/observations`` of an MCAP recording, in file order, read by mcap's own ROS 2 decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        messages = reader.iter_decoded_messages(topics=["/observations"], log_time_order=False)
        return [np.asarray(m.position, dtype=np.float64) for *_, m in messages]


def evaluate_workers(setting: Setting, tmp_path: Path, net: Any) -> np.ndarray:
    """``fmu-bridge evaluate a=sequence b=sequence --workers 2 --episodes 2``: each agent a cell
    in a worker process, each recorded to MCAP and its observations read back."""
    from agents.evaluate import evaluate

    path = tmp_path / "evaluate.yaml"
    path.write_text(yaml.safe_dump(with_sequence(experiment(setting, tmp_path))))
    result = evaluate(
        ["a=sequence", "b=sequence"],
        path,
        episodes=len(EPISODES),
        seed=EPISODES[0],
        workers=2,
        record_dir=tmp_path / "recordings",
    )
    assert len(result.recordings) == 2
    cells = []
    for name, recording in zip(result.agents, result.recordings):
        lengths = [len(trace.time_s) for trace in result.traces[(name, "nominal")]]
        assert lengths == [STEPS + 1] * len(EPISODES), f"episodes of {lengths} samples"
        cells.append(np.asarray(recorded_observations(recording)))
    np.testing.assert_array_equal(cells[1], cells[0])  # the two workers agree
    return cells[0]


PATHS: dict[str, Callable[[Setting, Path], np.ndarray]] = {
    "batch-1": batch_of(1),
    "batch-3": batch_of(3),
    "system-component": system_component,
    "deployed-agent": deployed_agent,
}
PROCESS_PATHS: dict[str, Callable[[Setting, Path, Any], np.ndarray]] = {
    "isolated": isolated,
    "node": node,
    "isolated-node": isolated_node,
    "component-in-node": component_in_node,
    "deployed-agent-on-node": deployed_agent_on_node,
    "evaluate-workers": evaluate_workers,
}


def check_cell(setting_name: str, path: Callable[[Setting, Path], np.ndarray], tmp_path: Path) -> None:
    """Run one cell: the path's two episodes equal the in-process FmuEnv's, or a named refusal."""
    setting = SETTINGS[setting_name]
    reference = in_process(setting, tmp_path)
    assert np.isfinite(reference).all() and len(reference) == len(EPISODES) * (STEPS + 1)
    try:
        got = path(setting, tmp_path)
    except (ConfigError, TransportError) as exc:  # a refusal (here or by a node) names the setting
        named = [key for key in setting.keys if key in str(exc)]
        assert named, f"the refusal names none of {setting.keys}: {exc}"
        return
    np.testing.assert_array_equal(got, reference)


@pytest.mark.parametrize("path", list(PATHS))
@pytest.mark.parametrize("setting", list(SETTINGS))
def test_in_process_path_equals_fmu_env(setting: str, path: str, tmp_path: Path) -> None:
    check_cell(setting, PATHS[path], tmp_path)


@pytest.mark.integration
@pytest.mark.parametrize("path", list(PROCESS_PATHS))
@pytest.mark.parametrize("setting", list(SETTINGS))
def test_process_path_equals_fmu_env(setting: str, path: str, tmp_path: Path, loopback: Any) -> None:
    check_cell(setting, lambda s, p: PROCESS_PATHS[path](s, p, loopback), tmp_path)


def test_two_episodes_of_the_reference_repeat_where_the_seed_does_not_matter(tmp_path: Path) -> None:
    """The reference itself: no randomisation, so both episodes are equal (the reset policy works)."""
    for name in ("fmi2-reset-auto", "fmi2-reset-restore", "fmi2-reset-reinstantiate", "fmi3-cs-parameters"):
        rows = in_process(SETTINGS[name], tmp_path)
        first, second = rows[: STEPS + 1], rows[STEPS + 1 :]
        np.testing.assert_array_equal(first, second)
