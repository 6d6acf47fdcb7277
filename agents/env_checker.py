"""stable-baselines3's env checker, offered to ``fmu-bridge check`` through an entry point."""

from __future__ import annotations

from typing import Any


def sb3_check(env: Any) -> None:
    """Run stable-baselines3's ``check_env`` (raises on a failure, warns on advice)."""
    from stable_baselines3.common.env_checker import check_env

    check_env(env, warn=True)
