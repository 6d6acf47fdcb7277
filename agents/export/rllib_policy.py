"""An RLlib-trained policy as the export path reads it: ``RUN/rllib_policy.npz``.

``train --engine rllib`` writes the deterministic path of the trained RLModule (its policy encoder
and policy head, as linear layers and activations) to the run folder; :func:`agents.export.extract.load_parts`
reads it like an SB3 model, so ``agent export onnx`` (and the C and FMU exports) need neither Ray
nor RLlib afterwards. Writing it needs Ray (:func:`write_policy` reads an RLlib checkpoint).

The head is the one RLlib's env runners apply with ``explore=False`` (``agents/rllib_train.py``):
``argmax`` of the logits for a discrete action space; else ``unsquash``: the first half of the
head's outputs (the Gaussian mean) mapped from [-1, 1] onto the Box and clipped to it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.export.ops import Op, network_ops
from bridge.errors import ConfigError

POLICY_FILE = "rllib_policy.npz"
MODULE_PATH = ("learner_group", "learner", "rl_module", "default_policy")


def module_dir(checkpoint: Path) -> Path:
    """The trained RLModule inside an RLlib algorithm checkpoint (the learner's copy)."""
    return checkpoint.joinpath(*MODULE_PATH)


def load_module(checkpoint: Path) -> Any:
    """The trained RLModule of an RLlib algorithm checkpoint (needs Ray)."""
    from ray.rllib.core.rl_module.rl_module import RLModule

    path = module_dir(checkpoint)
    if not path.is_dir():
        inner = path.relative_to(checkpoint)
        raise ConfigError(f"not an RLlib algorithm checkpoint: it has no {inner} [{checkpoint}]")
    return RLModule.from_checkpoint(str(path))


def _leaves(module: Any) -> list[Any]:
    children = list(module.children())
    if not children:
        return [module]
    return [leaf for child in children for leaf in _leaves(child)]


def policy_ops(module: Any, algo: str) -> tuple[list[Op], str]:
    """The module's deterministic path as ops, and its head (``unsquash`` or ``argmax``)."""
    import gymnasium as gym

    if algo == "PPO":
        encoder = module.encoder
        actor = getattr(encoder, "actor_encoder", None) or encoder.encoder  # separate or shared layers
    elif algo == "SAC":
        actor = module.pi_encoder
    else:
        raise ConfigError(f"RLlib algorithm {algo!r} cannot be exported; supported: PPO, SAC")
    ops = network_ops([*_leaves(actor), *_leaves(module.pi)])
    space = module.action_space
    if isinstance(space, gym.spaces.Discrete):
        return ops, "argmax"
    if not isinstance(space, gym.spaces.Box):
        raise ConfigError(f"action space {space} cannot be exported; supported: Box and Discrete")
    n = int(np.prod(space.shape))
    last = ops[-1]
    if last.kind != "linear" or last.weight is None or last.bias is None:
        raise ConfigError(f"the {algo} policy head does not end in a linear layer; it cannot be exported")
    if len(last.weight) == 2 * n:  # mean and log std: the deterministic action reads the mean
        ops[-1] = Op("linear", last.weight[:n], last.bias[:n])
    elif len(last.weight) != n:
        raise ConfigError(f"the {algo} policy head has {len(last.weight)} outputs for {n} actions")
    return ops, "unsquash"


def write_policy(checkpoint: Path, run_dir: Path, algo: str) -> Path:
    """``RUN/rllib_policy.npz`` from the checkpoint's trained module."""
    ops, head = policy_ops(load_module(checkpoint), algo)
    arrays: dict[str, Any] = {"algo": np.asarray(algo), "head": np.asarray(head)}
    arrays["kinds"] = np.asarray([op.kind for op in ops])
    for i, op in enumerate(ops):
        if op.kind == "linear":
            arrays[f"weight_{i}"], arrays[f"bias_{i}"] = op.weight, op.bias
    out = run_dir / POLICY_FILE
    np.savez(out, **arrays)
    return out


def read_policy(run_dir: Path) -> tuple[str, list[Op], str]:
    """(algorithm, ops, head) from ``RUN/rllib_policy.npz``."""
    path = run_dir / POLICY_FILE
    if not path.is_file():
        raise ConfigError(
            f"{run_dir} was trained with --engine rllib but has no {POLICY_FILE}: training did not finish; "
            "train again (the file is written after the last iteration)"
        )
    with np.load(path, allow_pickle=False) as data:
        kinds = [str(k) for k in data["kinds"]]
        ops = [
            Op(k, data[f"weight_{i}"], data[f"bias_{i}"]) if k == "linear" else Op(k)
            for i, k in enumerate(kinds)
        ]
        return str(data["algo"]), ops, str(data["head"])


def actor_from_ops(ops: list[Op]) -> list[Any]:
    """Torch modules computing ``ops`` (float32, as the policy was trained)."""
    import torch
    from torch import nn

    modules: list[Any] = []
    for op in ops:
        if op.kind == "linear":
            assert op.weight is not None and op.bias is not None
            layer = nn.Linear(op.weight.shape[1], op.weight.shape[0])
            with torch.no_grad():
                layer.weight.copy_(torch.as_tensor(op.weight, dtype=torch.float32))
                layer.bias.copy_(torch.as_tensor(op.bias, dtype=torch.float32))
            modules.append(layer)
        else:
            modules.append({"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}[op.kind]())
    return modules
