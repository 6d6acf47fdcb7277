"""What the vector envs share about Gymnasium's autoreset modes, per-env seeds and scenarios, and
what one env's error does to the batch (no FMU runtime: the vector env over nodes imports it too)."""

from __future__ import annotations

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
