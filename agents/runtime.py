"""Torch-free inference: a policy exported by ``fmu-bridge agent export onnx``, run with onnxruntime.

This module imports neither torch nor stable-baselines3, so a deployed agent runs where only
numpy and onnxruntime are installed. :class:`OnnxPolicy` has the interface of
:class:`agents.policies.Sb3Policy` (``reset(task, seed)``, ``act(obs, signals)``): it takes the
Task's observation vector and returns the agent's action, normalisation and clipping included.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bridge.errors import ConfigError, DependencyMissing

METADATA_KEY = "fmu_bridge"  # the same key as agents.export.onnx (not imported: that module needs torch)


def onnx_file(path: Path) -> Path:
    """``policy.onnx`` of a run directory, or the given ``.onnx`` file."""
    if path.is_file() and path.suffix == ".onnx":
        return path
    run_dir = path if path.is_dir() else path.parent
    candidate = run_dir / "policy.onnx"
    if not candidate.is_file():
        raise ConfigError(
            f"{path} has no policy.onnx: export it first with `fmu-bridge agent export onnx {run_dir}` "
            "(on a machine with torch), then copy the run directory"
        )
    return candidate


class OnnxPolicy:
    """A deterministic policy from an ONNX graph (one thread: lowest latency for one observation)."""

    def __init__(self, path: Path, name: str | None = None) -> None:
        try:
            import onnxruntime as ort
        except ImportError as exc:
            raise DependencyMissing(
                "onnxruntime", "the onnx runtime of deployed agents", 'pip install "fmu-bridge[deploy]"'
            ) from exc
        self.path = onnx_file(path)
        self.name = name or self.path.parent.name
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        try:
            self._session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        except Exception as exc:
            raise ConfigError(f"cannot load the ONNX policy {self.path}: {exc}") from exc
        raw = self._session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        if raw is None:
            raise ConfigError(f"{self.path} has no {METADATA_KEY!r} metadata: export it with fmu-bridge")
        self.metadata: dict[str, Any] = json.loads(raw)
        self._discrete = self.metadata["action_kind"] == "discrete"
        self._feed: dict[str, Any] = {}

    def reset(self, task: Any, seed: int | None) -> None:
        """Check that the graph fits the task (observation size and action inputs)."""
        expected = len(self.metadata["observation_names"])
        actual = int(np.prod(task.observation_space.shape))
        inputs = list(task.action_inputs)
        if expected != actual or inputs != self.metadata["action_inputs"]:
            raise ConfigError(
                f"{self.path} was exported for {expected} observations acting on "
                f"{self.metadata['action_inputs']}, the experiment has {actual} acting on {inputs}: "
                "deploy with the experiment of the run (its experiment.yaml)"
            )

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        batch = np.asarray(obs, dtype=np.float32).reshape(1, -1)
        action = self._session.run(["action"], {"observation": batch})[0][0]
        return int(action) if self._discrete else action

    def predict(self, observations: Any) -> tuple[Any, Any]:
        """A batch ``[n, n_obs]`` -> (actions, input values): for checks and benchmarks."""
        batch = np.asarray(observations, dtype=np.float32)
        action, inputs = self._session.run(["action", "inputs"], {"observation": batch})
        return action, inputs
