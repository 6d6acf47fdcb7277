"""What the vector envs share about Gymnasium's autoreset modes, per-env seeds and scenarios, and
what one env's error does to the batch (no FMU runtime: the vector env over nodes imports it too)."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any, Literal, cast, get_args

from gymnasium.vector import AutoresetMode

from bridge.errors import ConfigError

OnError = Literal["raise", "truncate"]


def on_error_mode(on_error: str) -> OnError:
    """``on_error`` if a vector env here offers it, else a ConfigError."""
    if on_error in get_args(OnError):
        return cast(OnError, on_error)
    raise ConfigError(f"on_error must be 'raise' or 'truncate', got {on_error!r}")


def autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """``mode`` (the enum or its value) if a vector env here offers it, else a ConfigError."""
    supported = (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP)
    try:
        value = AutoresetMode(mode)
    except ValueError:
        value = None
    if value not in supported:
        raise ConfigError(
            f"autoreset_mode must be one of {[m.value for m in supported]} (gymnasium's AutoresetMode), "
            f"got {mode!r}"
        )
    assert value is not None
    return value


def same_step_refusal(name: str, declared: Any) -> str:
    """Why a vector env in ``declared`` autoreset mode cannot feed RLlib, and what to do instead."""
    return (
        f"RLlib's env runner reads vector envs by NEXT_STEP autoreset rules, but this {name} declares "
        f"autoreset_mode {getattr(declared, 'value', declared)!r}: its episodes would end in the next "
        f"episode's reset state and lose their first step. Build it with "
        f"{name}(..., autoreset_mode=AutoresetMode.NEXT_STEP), or register the experiment with "
        "bridge.env.rllib.register(experiment) (docs/ray.md)"
    )


def refuse_same_step_under_rllib(mode: AutoresetMode, name: str) -> None:
    """ConfigError when a SAME_STEP vector env is being built by RLlib (an RLlib module calls its
    constructor, e.g. an env runner over ``register_env(..., lambda cfg: BatchVectorEnv(...))``):
    RLlib never reads ``metadata["autoreset_mode"]`` and would corrupt every episode silently.
    Reads the caller frames once, at construction; Ray need not be installed."""
    if mode is not AutoresetMode.SAME_STEP or "ray.rllib" not in sys.modules:
        return
    frame = sys._getframe(1)
    while frame is not None:
        if str(frame.f_globals.get("__name__", "")).startswith("ray.rllib."):
            raise ConfigError(same_step_refusal(name, mode))
        frame = frame.f_back  # type: ignore[assignment]
    return


def env_seeds(seed: int | list[int | None] | None, n: int) -> list[int | None]:
    """One seed per env: ``seed + i``, a list of ``n`` as given, or all None."""
    if isinstance(seed, list):
        if len(seed) != n:
            raise ConfigError(f"reset(seed=[...]) needs {n} seeds (one per env), got {len(seed)}")
        return list(seed)
    return [None] * n if seed is None else [seed + i for i in range(n)]


def env_scenarios(options: Mapping[str, Any] | None, n: int) -> list[Any]:
    """One scenario per env from reset's ``options``: its ``scenario`` list as given, else its one
    ``scenario`` (a name, or None: each env's schedule picks) for all ``n``."""
    scenario = (options or {}).get("scenario")
    return scenario if isinstance(scenario, list) else [scenario] * n
