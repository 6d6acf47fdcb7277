"""``NodeVectorEnv``: a Gymnasium ``VectorEnv`` over K nodes, each a model served over Zenoh.

It steps the nodes through a :class:`~bridge.env.vec.RemoteVecEnv` (the same ``RemotePlant``
pieces as stable-baselines3's remote vector env): every action goes out before any answer is
awaited, so K nodes on other machines step in parallel and a vector step costs one round trip,
not K in series. Dead or hung nodes are replaced by spares (``replace_dead=True`` with a node
pattern), and ``claim=True`` leases each node as it is taken so that vector envs drawing on one
pool (one per Ray env runner) never share a node.

Autoreset follows ``autoreset_mode``, declared in ``metadata["autoreset_mode"]`` as
:class:`~bridge.env.batch.BatchVectorEnv` does:

- ``SAME_STEP`` (default): an env whose episode ended is reset in the same step; its last
  observation and info are in ``infos["final_obs"]`` / ``infos["final_info"]`` and the new
  episode's reset info in ``infos["reset_info"]`` (each with its ``_``-prefixed mask).
- ``NEXT_STEP`` (gymnasium's default, the one RLlib reads): the step that ends an episode returns
  its last observation with ``terminated``/``truncated`` and its info (``reason``, and
  ``plant_error`` after a failure); the next step resets that env (its action is ignored, reward
  0, not done) and returns its reset info. A node replaced by a spare shows ``node_replaced``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from bridge.env.autoreset import autoreset_mode as _autoreset_mode
from bridge.env.autoreset import env_seeds as _seeds
from bridge.env.vec import RemoteVecEnv, Result
from bridge.experiment.config import Experiment

ObsArray = npt.NDArray[np.float32]


class NodeVectorEnv(VectorEnv[ObsArray, Any, Any]):
    """A Gymnasium ``VectorEnv`` of ``n_envs`` nodes.

    Args:
        experiment: the experiment the nodes serve.
        nodes: node names, or a glob pattern matched against live nodes (extra matches are spares).
        n_envs: how many nodes to drive (default: every listed or matching node).
        autoreset_mode: ``AutoresetMode.SAME_STEP`` (default) or ``AutoresetMode.NEXT_STEP`` (or
            their values); declared in ``metadata["autoreset_mode"]``.
        remote: passed on to :class:`RemoteVecEnv` (``options``, ``session``, ``prefix``,
            ``timeout_s``, ``replace_dead``, ``replace_wait_s``, ``on_error``, ``claim``,
            ``discovery_timeout_s``).
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(
        self,
        experiment: Experiment | str | Path,
        nodes: Sequence[str] | str,
        *,
        n_envs: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.SAME_STEP,
        **remote: Any,
    ) -> None:
        mode = _autoreset_mode(autoreset_mode)
        self.nodes = RemoteVecEnv(experiment, nodes, n_envs=n_envs, **remote)
        self.metadata = {**type(self).metadata, "autoreset_mode": mode}
        self.autoreset_mode = mode
        self.num_envs = self.nodes.num_envs
        self.single_observation_space = self.nodes.observation_space
        self.single_action_space = self.nodes.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self._to_reset = np.zeros(self.num_envs, dtype=bool)  # NEXT_STEP: ended last step
        self._obs: list[Any] = [None] * self.num_envs

    @property
    def node_names(self) -> list[str]:
        """The node each env drives now (a replaced node's spare in its place)."""
        return self.nodes.node_names

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        seeds = _seeds(seed, self.num_envs)
        scenario = (options or {}).get("scenario")
        scenarios = scenario if isinstance(scenario, list) else [scenario] * self.num_envs
        self.nodes._last_obs = list(self._obs)
        infos: dict[str, Any] = {}
        for i in range(self.num_envs):
            option = {"scenario": scenarios[i]} if scenarios[i] is not None else None
            self._obs[i], info = self.nodes._reset_one(i, seeds[i], option)
            infos = self._add_info(infos, info, i)
        self._to_reset[:] = False
        return np.stack(self._obs), infos

    def step(self, actions: Any) -> tuple[ObsArray, Any, Any, Any, dict[str, Any]]:
        n = self.num_envs
        reward = np.zeros(n, dtype=np.float64)
        terminated, truncated = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        infos: dict[str, Any] = {}
        self.nodes._last_obs = list(self._obs)
        if self.autoreset_mode is AutoresetMode.NEXT_STEP:
            resetting = np.flatnonzero(self._to_reset).tolist()
            stepping = [i for i in range(n) if not self._to_reset[i]]
            results = self.nodes.step_envs(actions, stepping)
            for i in resetting:
                self._obs[i], info = self.nodes._reset_one(i)
                infos = self._add_info(infos, info, i)
            for i in stepping:
                self._obs[i], reward[i], terminated[i], truncated[i], info = _result(results[i])
                infos = self._add_info(infos, info, i)
            self._to_reset[:] = terminated | truncated
        else:
            results = self.nodes.step_envs(actions)
            for i in range(n):
                obs, reward[i], terminated[i], truncated[i], info = _result(results[i])
                if terminated[i] or truncated[i]:
                    self._obs[i], reset_info = self.nodes._reset_one(i)
                    end = {"final_obs": obs, "final_info": info, "reset_info": reset_info}
                    infos = self._add_info(infos, end, i)
                else:
                    self._obs[i] = obs
                    infos = self._add_info(infos, info, i)
        return np.stack(self._obs), reward, terminated, truncated, infos

    def close_extras(self, **kwargs: Any) -> None:
        self.nodes.close()


def _result(result: Result | None) -> Result:
    assert result is not None  # every env asked to step has a result (or the error was raised)
    return result
