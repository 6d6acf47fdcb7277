"""A trained agent as a node: ``fmu-bridge agent run MODEL --config experiment.yaml``.

It subscribes to an observation source (an FMU node's outputs over the native protocol, or any
``sensor_msgs/msg/JointState`` topic over the ROS 2 view: a real robot's too), applies exactly
the training-time Task observation processing (selection, scaling, history, VecNormalize
statistics), runs deterministic inference on the CPU and publishes the actions. Sensor and
actuator noise of the experiment are training-time randomisation and are left out here.
Missing or late observations trigger a configured rule (hold the last action, or a safe one).
"Late" is ``timeout_s`` for a real-time source; a lockstep node answers an action when its plant
has stepped, which may take seconds: there an observation is late only past the node's
deadlines (``bridge.net.deadlines``: ``timeout_s`` as the floor, the node's own deadline, and the
slowest step measured), so a slow plant at work is not taken for a missing one.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from agents.latency import LatencyWindow
from agents.policies import Policy
from bridge.errors import BridgeError, ConfigError
from bridge.experiment.config import Experiment, Noise, load_experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, timing
from bridge.fmu.vocab import ModelInfo
from bridge.net import protocol as proto
from bridge.net.deadlines import Deadlines
from bridge.task.core import Task

_log = logging.getLogger(__name__)
Transport = Literal["zenoh", "ros2", "rclpy"]


@dataclass
class DeploySettings:
    transport: Transport = "zenoh"
    node: str = "fmu"
    prefix: str = proto.DEFAULT_PREFIX
    observation_topic: str | None = None  # ROS: default /<node>/outputs
    action_topic: str | None = None  # ROS: default /<node>/actions
    missing: Literal["hold", "safe"] = "hold"
    safe_inputs: list[float] | None = None
    timeout_s: float = 0.5
    scenario: str | None = None
    domain_id: int | None = None
    namespace: str = "/"
    runtime: Literal["torch", "onnx", "fmu", "baseline"] = "torch"


@dataclass
class Stats:
    observations: int = 0
    actions: int = 0
    missing_events: int = 0
    latencies_s: LatencyWindow = field(default_factory=LatencyWindow)  # bounded: the recent window

    def summary(self) -> dict[str, float]:
        return {
            "observations": self.observations,
            "actions": self.actions,
            "missing_events": self.missing_events,
            "latency_median_us": self.latencies_s.quantile(0.5) * 1e6,
            "latency_p99_us": self.latencies_s.quantile(0.99) * 1e6,
        }


def deployment_experiment(run_or_model: Path, config: Path | None) -> tuple[Experiment, Path]:
    """The experiment the agent was trained on (the run's frozen copy unless --config is given)."""
    run_dir = run_or_model if run_or_model.is_dir() else run_or_model.parent
    path = config or run_dir / "experiment.yaml"
    if not path.is_file():
        raise ConfigError(f"no experiment for {run_or_model}: pass --config experiment.yaml")
    experiment = load_experiment(path)
    return experiment.model_copy(update={"noise": Noise()}), path


def deployed_checkpoint(run_or_model: Path, runtime: str) -> str:
    """Which file ``agent run`` deploys, and what is known of it: ``best_model.zip`` (the best
    periodic evaluation: its mean reward and step) before the final ``model.zip``."""
    import json

    if runtime == "baseline":
        return f"baseline {run_or_model} of the experiment's evaluation.baselines (no checkpoint)"
    if runtime == "onnx":
        from agents.runtime import onnx_file

        return f"checkpoint {onnx_file(run_or_model)} (ONNX export)"
    if runtime == "fmu":
        from agents.export.fmu_runner import policy_fmu_file

        return f"checkpoint {policy_fmu_file(run_or_model)} (policy FMU export)"
    from agents.policies import _model_file

    path = _model_file(run_or_model)
    run_dir = path.parent
    if path.name == "best_model.zip" and (run_dir / "evaluations.npz").is_file():
        with np.load(run_dir / "evaluations.npz") as data:
            means = data["results"].mean(axis=1)
            best = int(np.argmax(means))
            return (
                f"checkpoint {path} (best evaluation: mean reward {means[best]:.1f} at step "
                f"{int(data['timesteps'][best]):,} of {len(means)} evaluations)"
            )
    run_file = run_dir / "run.json"
    steps = json.loads(run_file.read_text()).get("timesteps") if run_file.is_file() else None
    return f"checkpoint {path}" + (f" (final model after {steps:,} steps)" if steps else "")


def model_info_for(
    experiment: Experiment, run_dir: Path, node_description: dict[str, Any] | None
) -> ModelInfo:
    """Variable metadata for the Task: the local FMU, else the run's snapshot, else the node's report."""
    from bridge.fmu.vocab import info_from_summary

    try:
        from bridge.fmu import read_model_info  # FMPy only where an FMU is read

        return read_model_info(resolve_fmu(experiment))
    except BridgeError:
        pass
    snapshot = run_dir / "model.json"
    if snapshot.is_file():
        import json

        return info_from_summary(json.loads(snapshot.read_text()))
    if node_description is not None:
        return info_from_summary(node_description["model"])
    raise ConfigError(
        "the FMU of the experiment is not on this machine and the run has no model.json: "
        "copy the FMU here, or deploy with --transport zenoh against its node"
    )


def _decade(n: int) -> bool:
    """1, 10, 100, ...: when a repeated event is worth another log line."""
    while n >= 10 and n % 10 == 0:
        n //= 10
    return n == 1


class DeployedAgent:
    """Receives observations, acts, publishes; thread-safe; ``close()`` stops it.

    ``lockstep``: the deadlines of a lockstep node (its next observation answers this agent's
    action); None for a real-time source, whose observations are late after ``timeout_s``.
    """

    def __init__(
        self,
        policy: Policy,
        experiment: Experiment,
        info: ModelInfo,
        settings: DeploySettings,
        publish: Any,
        *,
        lockstep: Deadlines | None = None,
    ) -> None:
        check_experiment(experiment, info)
        self.task = Task(experiment, info.variables, timing(experiment, info))
        self.policy, self.settings, self._publish = policy, settings, publish
        self.stats = Stats()
        self._rng = np.random.default_rng(0)
        self._lock = threading.Lock()
        self._publishing = threading.Lock()  # close() waits for a publish under way
        self._episode_key: Any = None
        self._sample = 0
        self._last_inputs: list[float] | None = None
        self._last_time = time.monotonic()
        self._acted_at: float | None = None  # when the last action answering an observation went out
        self._lockstep = lockstep
        self._missing_in_a_row = 0  # missing-observation events since the last observation
        self._stop = threading.Event()
        self._warm_up()
        self._watchdog = threading.Thread(target=self._watch, name="agent-watchdog", daemon=True)
        self._watchdog.start()

    def _warm_up(self) -> None:
        """The first inference of a torch model is slow (allocations, kernel choice): do it before
        observations arrive, so the first real action is on time. One thread: lower latency.
        A baseline has nothing to warm up (and acts only within an episode: its controller state),
        nor has compiled C (a policy FMU, which also reads the task's signals of an episode)."""
        if self.settings.runtime in ("baseline", "fmu"):
            return
        if self.settings.runtime == "torch":  # the onnx runtime must work without torch
            import torch

            torch.set_num_threads(1)
        space = self.task.observation_space
        for _ in range(3):
            self.policy.act(np.zeros(space.shape, dtype=np.float32), {})

    def observe(
        self, outputs: Sequence[float], *, episode: Any = None, step: int | None = None
    ) -> list[float]:
        """One observation in, one action out (physical input values, also published)."""
        if self._stop.is_set():  # closing: late messages are ignored
            return []
        start = time.perf_counter()
        with self._lock:
            values = [float(v) for v in outputs]
            if episode != self._episode_key or step == 0 or self._last_inputs is None:
                self._start_episode(episode)
            else:
                self._sample = self._sample + 1 if step is None else step
                if self._lockstep is not None and self._acted_at is not None:  # the plant's step, measured
                    self._lockstep.stepped(time.monotonic() - self._acted_at)
            if self._missing_in_a_row:
                _log.info("observations again after %d missing-observation events", self._missing_in_a_row)
                self._missing_in_a_row = 0
            obs = self.task.observe(values, self._sample, self._rng)
            action = self.policy.act(obs, self.task.controller_signals())
            # all node inputs: the agent's, then the scenario's profile inputs (simulated disturbances)
            inputs = list(self.task.action_to_inputs(action, self._sample, self._rng))
            self._last_inputs, self._last_time = inputs, time.monotonic()
            self._acted_at = self._last_time
            self.stats.observations += 1
        if not self._send(inputs, self._sample):
            return inputs
        self.stats.actions += 1
        self.stats.latencies_s.append(time.perf_counter() - start)
        return inputs

    def _start_episode(self, episode: Any) -> None:
        self._episode_key, self._sample = episode, 0
        self.task.new_episode(self._rng, self.settings.scenario)
        self.policy.reset(self.task, None)

    def late_after_s(self) -> float:
        """Seconds without an observation before the missing-observation rule acts."""
        lockstep = self._lockstep
        return lockstep.step_s() if lockstep is not None else self.settings.timeout_s

    def _watch(self) -> None:
        while not self._stop.wait(self.settings.timeout_s / 4):
            with self._lock:
                late_after_s = self.late_after_s()
                late = time.monotonic() - self._last_time > late_after_s
                if not late or self._last_inputs is None:
                    continue
                inputs = self._last_inputs if self.settings.missing == "hold" else self._safe()
                self._last_time = time.monotonic()
                self.stats.missing_events += 1
                self._missing_in_a_row += 1
                in_a_row = self._missing_in_a_row
            if _decade(in_a_row):  # the 1st, 10th, 100th, ...: a node gone for hours is a few lines
                _log.warning(
                    "no observation for %.0f ms (%d time%s in a row; told again at %d): %s action %s",
                    late_after_s * 1e3 * in_a_row,
                    in_a_row,
                    "" if in_a_row == 1 else "s",
                    in_a_row * 10,
                    "holding the last" if self.settings.missing == "hold" else "publishing the safe",
                    inputs,
                )
            self._send(inputs, self._sample)

    def _send(self, inputs: list[float], sample: int) -> bool:
        """Publish unless closing: an observation that arrives while the transport closes must not
        publish on a closed publisher (a ROS publisher raises then)."""
        with self._publishing:
            if self._stop.is_set():
                return False
            self._publish(inputs, sample)
            return True

    def _safe(self) -> list[float]:
        n = len(self.task.action_inputs)
        safe = list(self.settings.safe_inputs) if self.settings.safe_inputs is not None else [0.0] * n
        return safe + (self._last_inputs or [])[n:]

    def close(self) -> None:
        """Stop acting; when it returns nothing is being or will be published."""
        self._stop.set()
        with self._publishing:  # a publish under way ends before the transport may close
            pass
        self._watchdog.join(timeout=2.0)
