"""The env side of remote FMU nodes: ``NodeClient``, ``RemoteFmuEnv`` and node discovery.

A remote env runs the same Task as ``FmuEnv`` (actions, observations, reward, termination,
scenarios and all randomness drawn from its own ``np_random``); only the model runs in the
node. So the same seed gives the same trajectory in-process and remote. The FMU need not exist
on this machine: the node reports its variables, and the Task is checked against them.
"""

from __future__ import annotations

import fnmatch
import logging
import threading
import time
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from bridge.env.fmu_env import as_experiment
from bridge.errors import BridgeError, ConfigError, StepTimeout, TransportError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, check_experiment, timing
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session, undeclare
from bridge.plant.vocab import info_from_summary
from bridge.task.core import Task

_log = logging.getLogger(__name__)
ObsType = npt.NDArray[np.float32]


class NodeClient:
    """Talks to one node: stamped actions out, the matching outputs frame back."""

    def __init__(
        self, session: Any, node: str, *, prefix: str = proto.DEFAULT_PREFIX, timeout_s: float = 5.0
    ) -> None:
        self.keys = proto.Keys(prefix, node)
        self.name = node
        self.timeout_s = timeout_s
        self._session = session
        self._event = threading.Event()
        self._want: tuple[int, int] = (-1, -1)
        self._frame: proto.Frame | None = None
        self.alive = True
        self.description = self._query_info()
        self._declared = [
            session.declare_subscriber(self.keys.outputs, self._on_frame),
            session.liveliness().declare_subscriber(self.keys.alive, self._on_liveliness, history=True),
        ]
        self._pub = session.declare_publisher(self.keys.actions)
        self._declared.append(self._pub)
        self._n_inputs = len(self.description["input_names"])

    def _query_info(self) -> dict[str, Any]:
        # A query sent before routes exist finds no queryable and returns at once: retry until the
        # timeout, so a just-opened session or a node that is still starting is found.
        deadline = time.monotonic() + self.timeout_s
        while True:
            remaining = deadline - time.monotonic()
            for reply in self._session.get(self.keys.info, timeout=max(0.05, min(remaining, 1.0))):
                if reply.ok is not None:
                    return proto.decode_json(reply.ok.payload.to_bytes(), f"info of node {self.name!r}")
            if remaining <= 0:
                break
            time.sleep(min(0.1, max(remaining, 0.0)))
        raise TransportError(
            f"no FMU node named {self.name!r} answers on {self.keys.info} within {self.timeout_s:g} s; "
            f"start one with `fmu-bridge node EXPERIMENT --name {self.name}` and check the Zenoh endpoints "
            "(`fmu-bridge nodes` lists the live ones)"
        )

    def _on_frame(self, sample: Any) -> None:
        try:
            frame = proto.decode(sample.payload.to_bytes())
        except TransportError:
            return
        if (frame.episode, frame.step) == self._want:
            self._frame = frame
            self._event.set()

    def _on_liveliness(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE:
            self.alive = False
            self._event.set()  # wake a waiting step at once
        else:
            self.alive = True

    def send_action(self, episode: int, step: int, inputs: list[float]) -> None:
        if not self.alive:
            raise self._dead(episode, step)
        self._frame = None
        self._event.clear()
        self._want = (episode, step)
        self._pub.put(proto.encode_values(proto.ACTION, episode, step, 0, inputs))

    def wait(self) -> proto.Frame:
        """The outputs frame for the last action; raises if the node died, rejected it or timed out."""
        episode, step = self._want
        if not self._event.wait(self.timeout_s):
            raise StepTimeout(
                f"node {self.name!r} did not answer step {step} of episode {episode} within "
                f"{self.timeout_s:g} s; it may be overloaded or unreachable (timeout_s sets the limit) "
                f"[{self.keys.base}]"
            )
        frame = self._frame
        if frame is None:
            raise self._dead(episode, step)
        if frame.kind == proto.REJECT:
            raise TransportError(
                f"node {self.name!r} rejected step {step} of episode {episode}: {frame.message}"
            )
        return frame

    def _dead(self, episode: int, step: int) -> TransportError:
        return TransportError(
            f"node {self.name!r} died during step {step} of episode {episode} (its liveliness token "
            f"disappeared); restart it, or let RemoteVecEnv replace dead nodes [{self.keys.base}]"
        )

    def reset(self, episode: int, values: dict[str, Any], inputs: list[float]) -> proto.Frame:
        request = proto.encode_json({"episode": episode, "values": values, "inputs": inputs})
        self._want = (episode, 0)
        for reply in self._session.get(self.keys.reset, payload=request, timeout=self.timeout_s):
            if reply.ok is not None:
                return proto.decode(reply.ok.payload.to_bytes())
            raise TransportError(
                f"node {self.name!r}: {reply.err.payload.to_bytes().decode(errors='replace')}"
            )
        raise StepTimeout(
            f"node {self.name!r} did not answer the reset of episode {episode} within "
            f"{self.timeout_s:g} s [{self.keys.reset}]"
        )

    def close(self) -> None:
        for entity in reversed(self._declared):
            try:
                undeclare(entity)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        self._declared = []


def check_node(
    experiment: Experiment, description: dict[str, Any], task_io: tuple[Any, Any], timing_: Timing
) -> None:
    """The node must serve the same model with the same timing and I/O as this env expects."""
    inputs, outputs = task_io
    node = description.get("node", "?")
    mismatches = []
    if list(inputs) != description["input_names"]:
        mismatches.append(f"inputs {list(inputs)} vs the node's {description['input_names']}")
    if list(outputs) != description["output_names"]:
        mismatches.append(f"outputs {list(outputs)} vs the node's {description['output_names']}")
    if abs(timing_.sampling_time_s - description["sampling_time_s"]) > 1e-12:
        mismatches.append(f"sampling time {timing_.sampling_time_s} vs {description['sampling_time_s']}")
    if mismatches:
        raise ConfigError(
            f"node {node!r} serves experiment {description.get('experiment')!r} with "
            f"{'; '.join(mismatches)}; start the node with the same experiment file ({experiment.source})"
        )


class RemoteFmuEnv(gym.Env[ObsType, Any]):
    """``FmuEnv`` with the model in a node (lockstep over Zenoh).

    Args:
        experiment: the experiment (the same file the node was started with).
        node: the node's name.
        options: how to open a Zenoh session (ignored when ``session`` is given).
        timeout_s: how long a step or reset may take before :class:`StepTimeout`.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        experiment: Experiment | str | Path,
        node: str,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        version: str | None = None,
    ) -> None:
        self.experiment = exp = as_experiment(experiment, version)
        if exp.hooks.state:
            raise ConfigError(
                "hooks.state changes the model between steps and runs in-process only; use FmuEnv"
            )
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        try:
            self.client = NodeClient(self._session, node, prefix=prefix, timeout_s=timeout_s)
            info = info_from_summary(self.client.description["model"])
            check_experiment(exp, info)
            self.timing = timing(exp, info)
            self.task = Task(exp, info.variables, self.timing)
            check_node(
                exp, self.client.description, (self.task.input_names, self.task.output_names), self.timing
            )
        except BaseException:
            self.close()
            raise
        self.node = node
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self.output_names = self.task.output_names
        self._episode = 0
        self._sample = 0
        self._done = True

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsType, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.task.sampler.restart()
        spec = self.task.new_episode(self.np_random, (options or {}).get("scenario"))
        self._episode += 1
        frame = self.client.reset(self._episode, spec.values, self.task.initial_inputs())
        obs = self.task.first_observation(frame.values.tolist(), self.np_random)
        self._sample, self._done = 0, False
        info = {
            "time_s": frame.sim_time_ns / 1e9,
            "step": 0,
            "outputs": frame.values,
            "scenario": spec.scenario,
            "drawn": dict(spec.drawn),
            "node": self.node,
        }
        return obs, info

    def step(self, action: Any) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        self.send(action)
        return self.receive()

    def send(self, action: Any) -> None:
        """First half of a step: map the action and send it (RemoteVecEnv sends to all nodes first)."""
        if self._done:
            raise BridgeError("step() called on a finished or never-reset episode: call reset() first")
        inputs = self.task.action_to_inputs(action, self._sample, self.np_random)
        self.client.send_action(self._episode, self._sample + 1, inputs)

    def receive(self) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Second half of a step: wait for this node's outputs and compute the task's result."""
        frame = self.client.wait()
        self._sample += 1
        info: dict[str, Any] = {"time_s": frame.sim_time_ns / 1e9, "step": self._sample}
        if frame.kind == proto.ERROR:  # the FMU failed: the episode is truncated, the node lives on
            self._done = True
            obs = self.task.observer.observe(self.task._signals, self.task.applied_inputs, self.np_random)
            info.update(reason="fmu-error", fmu_error=frame.message, outputs=np.zeros(len(self.output_names)))
            return obs, 0.0, False, True, info
        outputs = frame.values
        obs, reward, terminated, truncated, reason = self.task.step_result(
            outputs.tolist(), self._sample, frame.terminated, self.np_random
        )
        info["outputs"] = outputs
        if terminated or truncated:
            info["reason"] = reason
            self._done = True
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        client = getattr(self, "client", None)
        if client is not None:
            client.close()
        if getattr(self, "_own_session", False) and getattr(self, "_session", None) is not None:
            self._session.close()
            self._session = None


def list_nodes(
    session: Any, *, prefix: str = proto.DEFAULT_PREFIX, pattern: str = "*", timeout_s: float = 2.0
) -> list[str]:
    """Names of the live nodes under ``prefix`` whose name matches the glob ``pattern``."""
    names = []
    for reply in session.liveliness().get(f"{prefix}/**/alive", timeout=timeout_s):
        if reply.ok is None:
            continue
        key = str(reply.ok.key_expr)
        name = key[len(prefix) + 1 : -len("/alive")]
        if fnmatch.fnmatchcase(name, pattern):
            names.append(name)
    return sorted(set(names))


def describe_nodes(
    session: Any, names: list[str], *, prefix: str = proto.DEFAULT_PREFIX, timeout_s: float = 2.0
) -> list[dict[str, Any]]:
    """Each node's info reply (nodes that do not answer in time are reported with an error)."""
    found = []
    for name in names:
        keys = proto.Keys(prefix, name)
        entry: dict[str, Any] = {"node": name, "error": f"no answer within {timeout_s:g} s"}
        for reply in session.get(keys.info, timeout=timeout_s):
            if reply.ok is not None:
                entry = proto.decode_json(reply.ok.payload.to_bytes(), f"info of {name}")
                break
        found.append(entry)
    return found
