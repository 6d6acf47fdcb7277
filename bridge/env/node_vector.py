"""``NodeVectorEnv``: a Gymnasium ``VectorEnv`` over K nodes, each a model served over Zenoh.

It steps the nodes through a :class:`~bridge.env.vec.RemoteVecEnv` (the same ``RemotePlant``
pieces as stable-baselines3's remote vector env): every action goes out before any answer is
awaited, so K nodes on other machines step in parallel and a vector step costs one round trip,
not K in series. Resets are parallel too: each env to reset sends its request and awaits the
reply on a thread of a pool, all at once (under NEXT_STEP alongside the step's actions), and
a failed reset is recovered once every reply is in. Dead or hung nodes are replaced by spares
(``replace_dead=True`` with a node pattern), and ``claim=True`` leases each node as it is taken
so that vector envs drawing on one pool (one per Ray env runner) never share a node.

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
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import wait as wait_all
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from bridge.env.autoreset import autoreset_mode as _autoreset_mode
from bridge.env.autoreset import env_scenarios, refuse_same_step_under_rllib
from bridge.env.autoreset import env_seeds as _seeds
from bridge.env.vec import RemoteVecEnv, Result
from bridge.errors import PlantError
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
        refuse_same_step_under_rllib(mode, "NodeVectorEnv")
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
        self._pool: ThreadPoolExecutor | None = None  # awaits the replies of resets in flight

    @property
    def node_names(self) -> list[str]:
        """The node each env drives now (a replaced node's spare in its place)."""
        return self.nodes.node_names

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[ObsArray, dict[str, Any]]:
        seeds = _seeds(seed, self.num_envs)
        scenarios = env_scenarios(options, self.num_envs)
        self.nodes._last_obs = list(self._obs)
        options_ = [{"scenario": s} if s is not None else None for s in scenarios]
        infos: dict[str, Any] = {}
        for i, (obs, info) in self._reset_all(range(self.num_envs), seeds, options_).items():
            self._obs[i] = obs
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
            stepping = [i for i in range(n) if not self._to_reset[i]]
            pending = self._send_resets(np.flatnonzero(self._to_reset).tolist())  # with the actions
            try:
                results = self.nodes.step_envs(actions, stepping)
            except BaseException:
                wait_all(pending.values())  # no reset left in flight
                raise
            for i, (obs, info) in self._await_resets(pending).items():
                self._obs[i] = obs
                infos = self._add_info(infos, info, i)
            for i in stepping:
                self._obs[i], reward[i], terminated[i], truncated[i], info = _result(results[i])
                infos = self._add_info(infos, info, i)
            self._to_reset[:] = terminated | truncated
        else:
            results = self.nodes.step_envs(actions)
            ended: dict[int, tuple[Any, dict[str, Any]]] = {}
            for i in range(n):
                obs, reward[i], terminated[i], truncated[i], info = _result(results[i])
                if terminated[i] or truncated[i]:
                    ended[i] = obs, info
                else:
                    self._obs[i] = obs
            new = self._reset_all(list(ended))
            for i in range(n):
                if i in ended:
                    self._obs[i], reset_info = new[i]
                    end = {"final_obs": ended[i][0], "final_info": ended[i][1], "reset_info": reset_info}
                    infos = self._add_info(infos, end, i)
                else:
                    infos = self._add_info(infos, _result(results[i])[4], i)
        return np.stack(self._obs), reward, terminated, truncated, infos

    def _reset_all(
        self,
        indices: Sequence[int],
        seeds: Sequence[int | None] | None = None,
        options: Sequence[dict[str, Any] | None] | None = None,
    ) -> dict[int, tuple[Any, dict[str, Any]]]:
        """Reset envs ``indices`` (with ``seeds[i]``, ``options[i]``): all requests in flight at once."""
        return self._await_resets(self._send_resets(indices, seeds, options), seeds, options)

    def _send_resets(
        self,
        indices: Sequence[int],
        seeds: Sequence[int | None] | None = None,
        options: Sequence[dict[str, Any] | None] | None = None,
    ) -> dict[int, Future[tuple[Any, dict[str, Any]]]]:
        """Start the resets of envs ``indices``, each awaited on a thread of the pool."""
        if not indices:
            return {}
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.num_envs, thread_name_prefix="node-reset")
        envs = self.nodes.envs
        return {
            i: self._pool.submit(
                envs[i].reset,
                seed=None if seeds is None else seeds[i],
                options=None if options is None else options[i],
            )
            for i in indices
        }

    def _await_resets(
        self,
        pending: dict[int, Future[tuple[Any, dict[str, Any]]]],
        seeds: Sequence[int | None] | None = None,
        options: Sequence[dict[str, Any] | None] | None = None,
    ) -> dict[int, tuple[Any, dict[str, Any]]]:
        """The first observation and info of each reset in ``pending``, once every reply is in; an
        env whose reset failed is then recovered as ``RemoteVecEnv`` does (a spare, or the error)."""
        wait_all(pending.values())
        done: dict[int, tuple[Any, dict[str, Any]]] = {}
        failed: dict[int, PlantError] = {}
        for i, future in pending.items():
            error = future.exception()
            if isinstance(error, PlantError):
                failed[i] = error
            elif error is not None:
                raise error
            else:
                done[i] = future.result()
                self.nodes._last_obs[i] = done[i][0]
        for i, error in sorted(failed.items()):
            seed = None if seeds is None else seeds[i]
            done[i] = self.nodes._reset_failed(i, error, seed, None if options is None else options[i])
        return done

    def close_extras(self, **kwargs: Any) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        self.nodes.close()


def _result(result: Result | None) -> Result:
    assert result is not None  # every env asked to step has a result (or the error was raised)
    return result
