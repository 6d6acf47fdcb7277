"""A policy network as what every export reads: its deterministic path as a list of operations
(linear layers and activations), taken from the torch modules of an SB3 or an RLlib policy."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError

FloatArray = npt.NDArray[np.float64]
ACTIVATIONS = ("tanh", "relu", "elu")


@dataclass(frozen=True)
class Op:
    """One step of the network: ``linear`` (weight ``(out, in)``, bias) or an activation."""

    kind: str
    weight: FloatArray | None = None
    bias: FloatArray | None = None


def network_ops(modules: list[Any]) -> list[Op]:
    """Flatten the modules into linear layers and activations; anything else is an error."""
    from torch import nn

    ops: list[Op] = []
    pending = list(modules)
    while pending:
        module = pending.pop(0)
        if isinstance(module, nn.Sequential) or type(module).__name__ == "FlattenExtractor":
            pending[:0] = list(module.children())
        elif isinstance(module, nn.Linear):
            weight = module.weight.detach().double().numpy()
            bias = module.bias.detach().double().numpy() if module.bias is not None else np.zeros(len(weight))
            ops.append(Op("linear", weight, bias))
        elif isinstance(module, nn.Tanh | nn.ReLU) or (isinstance(module, nn.ELU) and module.alpha == 1.0):
            ops.append(Op(type(module).__name__.lower()))
        elif not isinstance(module, nn.Flatten | nn.Identity):
            raise ConfigError(
                f"layer {type(module).__name__} cannot be exported to C: policies must be MLPs of "
                f"Linear layers and {', '.join(ACTIVATIONS)} activations (SB3's MlpPolicy)"
            )
    return ops
