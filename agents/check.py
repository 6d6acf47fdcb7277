"""``fmu-bridge agent check RUN --recording eval.mcap``: a deployment checked against a recording.

The recorded observations (``/outputs``: the plant's outputs, by joint name) are replayed through
the runtime that will be deployed (torch, ONNX or the policy FMU) with the deployment's experiment
(``--config``; default: the run's own), and each action is compared with the one recorded
(``/actions``, same stamp). Beside the largest action difference and the inference latency
percentiles it lists every mismatch of the deployment's mapping against the trained one: joint
names missing or extra, their order, and the observation scale and offset or action range of each
joint, the mistakes most often made when a trained policy meets a real robot's topics.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.deploy import DeployedAgent, DeploySettings, deployment_experiment, model_info_for
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment
from bridge.recording.meta import ACTIONS, OUTPUTS
from bridge.recording.reader import read_recording

RUNTIMES = ("torch", "onnx", "fmu")


@dataclass
class CheckReport:
    runtime: str
    samples: int
    compared: int
    max_action_difference: float
    differing: int  # samples whose action differs by more than the tolerance
    tolerance: float
    latency_us: dict[str, float]
    mapping: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.mapping and self.compared > 0 and self.max_action_difference <= self.tolerance


def _scale(experiment: Experiment, name: str) -> str:
    scale = experiment.observations.scale
    if isinstance(scale, dict):
        if name not in scale:
            return "auto"
        low, high = scale[name]
        return f"scale {(high - low) / 2:g}, offset {(high + low) / 2:g}"
    return str(scale)


def _action_range(experiment: Experiment, name: str) -> str:
    actions = experiment.actions
    if name in actions.levels:
        return f"levels {actions.levels[name]}"
    return f"low {actions.low.get(name, 'model min')}, high {actions.high.get(name, 'model max')}"


def mapping_mismatches(trained: Experiment, deployed: Experiment) -> list[str]:
    """How the deployment's observation and action mapping differs from the trained one."""
    found: list[str] = []
    for what, old, new in (
        ("observed joints", trained.observations.outputs, deployed.observations.outputs),
        ("action joints", trained.actions.inputs, deployed.actions.inputs),
    ):
        missing, extra = [n for n in old if n not in new], [n for n in new if n not in old]
        if missing or extra:
            found.append(f"{what}: names differ: trained on {old}, deployed with {new}")
        elif old != new:
            found.append(f"{what}: order differs: trained on {old}, deployed with {new}")
    for name in trained.observations.outputs:
        if name in deployed.observations.outputs and _scale(trained, name) != _scale(deployed, name):
            found.append(
                f"observation {name!r}: {_scale(deployed, name)} deployed, {_scale(trained, name)} trained"
            )
    if trained.observations.history != deployed.observations.history:
        found.append(
            f"observation history: {deployed.observations.history} deployed, "
            f"{trained.observations.history} trained"
        )
    for name in trained.actions.inputs:
        if name in deployed.actions.inputs and _action_range(trained, name) != _action_range(deployed, name):
            found.append(
                f"action {name!r}: {_action_range(deployed, name)} deployed, "
                f"{_action_range(trained, name)} trained"
            )
    return found


def _episodes(stamps: np.ndarray) -> np.ndarray:
    """Episode number of each sample: a stamp that does not increase starts a new episode."""
    starts = np.concatenate(([0], (np.diff(stamps) <= 0).astype(np.int64)))
    return np.cumsum(starts)


class _FmuRuntime:
    """The exported policy FMU: physical outputs in, physical inputs out."""

    def __init__(self, run_dir: Path) -> None:
        from agents.export.fmu_runner import FmuPolicy, policy_fmu_file

        self.policy = FmuPolicy(policy_fmu_file(run_dir))  # the file `agent run --runtime fmu` deploys

    def act(self, named: dict[str, float]) -> dict[str, float]:
        try:
            values = [named[n] for n in self.policy.input_names]
        except KeyError as exc:
            raise ConfigError(f"the policy FMU reads {exc}, which the recording's outputs lack") from None
        return dict(zip(self.policy.output_names, self.policy.act(values).tolist()))

    def close(self) -> None:
        self.policy.close()


def check_deployment(
    run: Path,
    recording: Path,
    *,
    config: Path | None = None,
    runtime: str = "torch",
    tolerance: float = 1e-6,
) -> CheckReport:
    """Replay ``recording``'s observations through the deployed runtime; compare the actions."""
    if runtime not in RUNTIMES:
        raise ConfigError(f"--runtime {runtime!r} is unknown; use torch, onnx or fmu")
    run_dir = run if run.is_dir() else run.parent
    trained, _ = deployment_experiment(run, None)
    deployed, _ = deployment_experiment(run, config)
    mapping = mapping_mismatches(trained, deployed)
    data = read_recording(recording)
    if OUTPUTS not in data.series or ACTIONS not in data.series:
        raise ConfigError(
            f"{recording} has no {OUTPUTS} and {ACTIONS}: record an evaluation "
            "(`fmu-bridge evaluate RUN --config experiment.yaml`)"
        )
    outputs, actions = data.series[OUTPUTS], data.series[ACTIONS]
    lacking = [n for n in deployed.observations.outputs if n not in outputs.names]
    if lacking:
        mapping.append(f"the recording has no joint(s) {lacking} (it has {outputs.names})")
        return CheckReport(runtime, len(outputs), 0, float("inf"), 0, tolerance, {}, mapping)
    out_episode = _episodes(outputs.stamp_ns)
    act_episode = _episodes(actions.stamp_ns)
    recorded = {(int(e), int(s)): row for e, s, row in zip(act_episode, actions.stamp_ns, actions.values)}
    columns = {n: outputs.names.index(n) for n in outputs.names}
    differences: list[float] = []
    latencies: list[float] = []
    act = _runtime(runtime, run, run_dir, deployed)
    try:
        step = 0
        for k, (episode, stamp, row) in enumerate(zip(out_episode, outputs.stamp_ns, outputs.values)):
            step = 0 if k == 0 or episode != out_episode[k - 1] else step + 1
            named = {n: float(row[i]) for n, i in columns.items()}
            start = time.perf_counter()
            inputs = act(named, int(episode), step)
            latencies.append(time.perf_counter() - start)
            expected = recorded.get((int(episode), int(stamp)))
            if expected is None:  # the last sample of an episode: no action followed it
                continue
            given = {n: float(v) for n, v in zip(actions.names, expected)}
            differences.append(max(abs(inputs[n] - given[n]) for n in deployed.actions.inputs if n in given))
    finally:
        close = getattr(act, "close", None)
        if close is not None:
            close()
    diffs = np.asarray(differences)
    lat = np.asarray(latencies) * 1e6
    latency = (
        {f"p{q}": float(np.percentile(lat, q)) for q in (50, 90, 99)} | {"max": float(lat.max())}
        if len(lat)
        else {}
    )
    return CheckReport(
        runtime,
        len(outputs),
        len(diffs),
        float(diffs.max()) if len(diffs) else float("inf"),
        int((diffs > tolerance).sum()),
        tolerance,
        latency,
        mapping,
    )


class _Acting:
    def __init__(self, agent: DeployedAgent, names: list[str]) -> None:
        self.agent, self.names = agent, names

    def __call__(self, named: dict[str, float], episode: int, step: int) -> dict[str, float]:
        outputs = [named[n] for n in self.agent.task.output_names]
        values = self.agent.observe(outputs, episode=episode, step=step)
        return dict(zip(self.names, values))

    def close(self) -> None:
        self.agent.close()


class _FmuActing:
    def __init__(self, runtime: _FmuRuntime) -> None:
        self.runtime = runtime

    def __call__(self, named: dict[str, float], episode: int, step: int) -> dict[str, float]:
        return self.runtime.act(named)

    def close(self) -> None:
        self.runtime.close()


def _runtime(runtime: str, run: Path, run_dir: Path, experiment: Experiment) -> Any:
    if runtime == "fmu":
        return _FmuActing(_FmuRuntime(run_dir))
    from agents.policies import load_policy

    settings = DeploySettings(runtime=runtime, timeout_s=3600.0)  # type: ignore[arg-type]  # checked
    info = model_info_for(experiment, run_dir, None)
    agent = DeployedAgent(load_policy(run, runtime), experiment, info, settings, lambda inputs, step: None)
    return _Acting(agent, list(agent.task.input_names))  # the agent's inputs, then profile inputs
