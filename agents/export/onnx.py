"""``fmu-bridge agent export onnx RUN``: the deployed policy as one ONNX graph.

Input ``observation`` (float32, ``[batch, n_obs]``, the Task's observation vector); outputs
``action`` (the agent's action: float32 ``[batch, n_actions]`` or int64 ``[batch]``, as
``model.predict(deterministic=True)`` returns it after VecNormalize) and ``inputs`` (float64
``[batch, n_inputs]``, the plant's input values in physical units). The metadata key
``fmu_bridge`` holds a JSON object with the names, units, algorithm, experiment and versions.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from agents.export.extract import PolicyParts, actor_modules, load_parts
from agents.export.rllib_policy import actor_from_ops
from bridge.errors import BridgeError

_log = logging.getLogger(__name__)
OPSET = 18
METADATA_KEY = "fmu_bridge"


def _wrapper(parts: PolicyParts, model: Any) -> Any:
    import torch
    from torch import nn

    def tensor(values: Any, dtype: Any = torch.float64) -> Any:
        return torch.as_tensor(np.asarray(values), dtype=dtype)

    class DeployedPolicy(nn.Module):
        """VecNormalize (float64, as numpy does it) -> network (float32) -> head -> input values."""

        def __init__(self) -> None:
            super().__init__()
            modules = actor_modules(model, parts.algo) if model is not None else actor_from_ops(parts.ops)
            self.actor = nn.Sequential(*modules)
            dim = len(parts.observation_names)
            normalise = parts.obs_mean is not None
            self.normalise = normalise
            self.register_buffer("mean", tensor(parts.obs_mean if normalise else np.zeros(dim)))
            self.register_buffer("std", tensor(parts.obs_std if normalise else np.ones(dim)))
            self.clip = parts.obs_clip
            self.register_buffer("low", tensor(parts.low, torch.float32))
            self.register_buffer("high", tensor(parts.high, torch.float32))
            self.register_buffer("centre", tensor(parts.centre))
            self.register_buffer("half_range", tensor(parts.half))
            self.register_buffer(
                "table", tensor(parts.table if parts.table is not None else np.zeros((1, 1)))
            )

        def forward(self, observation: Any) -> tuple[Any, Any]:
            x = observation
            if self.normalise:
                x = torch.clamp((x.double() - self.mean) / self.std, -self.clip, self.clip).float()
            y = self.actor(x)
            low, high = self.get_buffer("low"), self.get_buffer("high")
            if parts.head == "argmax":
                action = torch.argmax(y, dim=1)
                return action, self.get_buffer("table")[action]
            if parts.head == "clip":
                action = torch.maximum(torch.minimum(y, high), low)
            elif parts.head == "unsquash":  # RLlib: [-1, 1] onto the Box, then clipped to it
                action = low + (y + 1.0) * (high - low) / 2.0
                action = torch.maximum(torch.minimum(action, high), low)
            else:
                squashed = torch.tanh(y) if parts.head == "squash" else y
                action = low + 0.5 * (squashed + 1.0) * (high - low)
            unit = torch.clamp(action.double(), -1.0, 1.0)
            return action, self.get_buffer("centre") + self.get_buffer("half_range") * unit

    return DeployedPolicy().eval()


def export_onnx(run: Path, out: Path | None = None) -> Path:
    """Write ``policy.onnx`` (default: in the run directory) and check it with ``onnx.checker``."""
    import onnx
    import torch

    parts, model = load_parts(run)
    run_dir = run if run.is_dir() else run.parent
    out = out or run_dir / "policy.onnx"
    module = _wrapper(parts, model)
    example = torch.zeros((1, len(parts.observation_names)), dtype=torch.float32)
    try:
        with warnings.catch_warnings():  # the TorchScript exporter (no onnxscript needed) is deprecated
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.onnx.export(
                module,
                (example,),
                str(out),
                input_names=["observation"],
                output_names=["action", "inputs"],
                dynamic_axes={"observation": {0: "batch"}, "action": {0: "batch"}, "inputs": {0: "batch"}},
                opset_version=OPSET,
                dynamo=False,
            )
    except Exception as exc:
        raise BridgeError(f"torch.onnx.export failed for {run}: {exc}; output: {out}") from exc
    graph = onnx.load(str(out))
    graph.doc_string = f"fmu-bridge policy: {parts.algo} on {parts.metadata['experiment']}"
    for key, value in {
        METADATA_KEY: json.dumps(parts.metadata),
        "algo": parts.algo,
        "experiment": parts.metadata["experiment"],
    }.items():
        entry = graph.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(graph, full_check=True)
    onnx.save(graph, str(out))
    _log.info("wrote %s", out)
    return out
