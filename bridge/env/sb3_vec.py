"""The parts of stable-baselines3's ``VecEnv`` interface every vector env here shares.

bridge never imports SB3: ``Sb3VecEnv`` implements the interface and registers each subclass as
a virtual subclass of SB3's ``VecEnv`` when SB3 is loaded, which is what SB3's ``isinstance``
checks need. Subclasses say where attributes live (``_attr_targets``) and implement reset,
step_async, step_wait, seed, set_options and close.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any

import numpy as np


class Sb3VecEnv:
    """SB3 ``VecEnv`` plumbing: attribute access, method calls, rendering stubs, seeding."""

    num_envs: int

    def __init__(self) -> None:
        module = sys.modules.get("stable_baselines3.common.vec_env.base_vec_env")
        if module is not None:
            module.VecEnv.register(type(self))

    def _attr_targets(self, indices: list[int]) -> list[Any]:
        """The objects holding the attributes of envs ``indices`` (the envs, or the vector env)."""
        return [self for _ in indices]

    def _indices(self, indices: int | Iterable[int] | None) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    @staticmethod
    def _new_seed(seed: int | None) -> int:
        if seed is None:
            return int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        return seed

    def step(self, actions: Any) -> Any:
        self.step_async(actions)  # type: ignore[attr-defined]
        return self.step_wait()  # type: ignore[attr-defined]

    def get_attr(self, attr_name: str, indices: int | Iterable[int] | None = None) -> list[Any]:
        return [getattr(t, attr_name) for t in self._attr_targets(self._indices(indices))]

    def has_attr(self, attr_name: str) -> bool:
        return hasattr(self._attr_targets([0])[0], attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: int | Iterable[int] | None = None) -> None:
        for target in self._attr_targets(self._indices(indices)):
            setattr(target, attr_name, value)

    def env_method(
        self, method_name: str, *args: Any, indices: int | Iterable[int] | None = None, **kwargs: Any
    ) -> list[Any]:
        targets = self._attr_targets(self._indices(indices))
        return [getattr(t, method_name)(*args, **kwargs) for t in targets]

    def env_is_wrapped(self, wrapper_class: type, indices: int | Iterable[int] | None = None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> list[None]:
        return [None] * self.num_envs

    def render(self, mode: str | None = None) -> None:
        return None

    @property
    def unwrapped(self) -> Sb3VecEnv:
        return self

    def getattr_recursive(self, name: str) -> Any:
        return getattr(self, name)

    def getattr_depth_check(self, name: str, already_found: bool) -> str | None:
        return (
            f"{type(self).__module__}.{type(self).__name__}"
            if hasattr(self, name) and already_found
            else None
        )
