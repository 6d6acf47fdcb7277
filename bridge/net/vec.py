"""``RemoteVecEnv``: stable-baselines3's VecEnv interface over N remote FMU nodes.

All actions go out first, then all replies are gathered, so nodes step in parallel and the
trainer waits once per vector step. Episodes auto-reset exactly as SB3 expects: the last
observation is in ``infos[i]["terminal_observation"]`` and ``TimeLimit.truncated`` marks
truncation. With ``replace_dead=True`` a node that dies is replaced by a spare live node (found
by the name pattern) and its episode is truncated, instead of failing the run.

bridge never imports stable-baselines3: this class implements the VecEnv interface and
registers itself as a virtual subclass of SB3's ``VecEnv`` whenever SB3 is loaded, which is
what SB3's ``isinstance`` checks need.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.env.fmu_env import as_experiment
from bridge.errors import ConfigError, TransportError
from bridge.experiment.config import Experiment
from bridge.net import protocol as proto
from bridge.net.remote import RemoteFmuEnv, list_nodes
from bridge.net.transport import ZenohOptions, open_session

_log = logging.getLogger(__name__)


class RemoteVecEnv:
    """N remote envs stepped in parallel (one per node).

    Args:
        experiment: the experiment the nodes serve.
        nodes: node names, or a glob pattern (``"worker-*"``) matched against live nodes.
        n_envs: how many envs (default: every listed or matching node); extra matches are spares.
        replace_dead: replace a dead node by a spare and truncate its episode, instead of raising.
    """

    def __init__(
        self,
        experiment: Experiment | str | Path,
        nodes: Sequence[str] | str,
        *,
        n_envs: int | None = None,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        replace_dead: bool = False,
        discovery_timeout_s: float = 10.0,
    ) -> None:
        _register_with_sb3()
        self.experiment = as_experiment(experiment)
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._prefix, self._timeout_s, self.replace_dead = prefix, timeout_s, replace_dead
        self._pattern = nodes if isinstance(nodes, str) else None
        names = self._discover(nodes, n_envs, discovery_timeout_s)
        self.envs: list[RemoteFmuEnv] = []
        try:
            for name in names:
                self.envs.append(self._connect(name))
        except BaseException:
            self.close()
            raise
        self.num_envs = len(self.envs)
        first = self.envs[0]
        self.observation_space, self.action_space = first.observation_space, first.action_space
        self.render_mode = None
        self.metadata: dict[str, Any] = {"render_modes": []}
        self._seeds: list[int | None] = [None] * self.num_envs
        self._options: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        self.reset_infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        self._actions: Any = None
        self._last_obs: list[npt.NDArray[np.float32]] = []

    # -- nodes ---------------------------------------------------------------------------------------
    def _discover(self, nodes: Sequence[str] | str, n_envs: int | None, timeout_s: float) -> list[str]:
        if not isinstance(nodes, str):
            names = list(nodes)
        else:  # nodes may still be starting: poll until enough are up or the timeout passes
            deadline = time.monotonic() + timeout_s
            while True:
                names = list_nodes(self._session, prefix=self._prefix, pattern=nodes, timeout_s=1.0)
                enough = len(names) >= n_envs if n_envs is not None else bool(names)
                if enough or time.monotonic() > deadline:
                    break
                time.sleep(0.2)
        wanted = n_envs or len(names)
        if wanted < 1 or len(names) < wanted:
            raise ConfigError(
                f"RemoteVecEnv needs {wanted or 'at least one'} node(s) matching {nodes!r} under "
                f"{self._prefix}/, found {names}; start them with `fmu-bridge node EXPERIMENT --name NAME`"
            )
        return names[:wanted]

    def _connect(self, name: str) -> RemoteFmuEnv:
        return RemoteFmuEnv(
            self.experiment, name, session=self._session, prefix=self._prefix, timeout_s=self._timeout_s
        )

    def _replace(self, index: int, error: TransportError) -> bool:
        if not self.replace_dead or self._pattern is None:
            return False
        in_use = {env.node for env in self.envs}
        for name in list_nodes(self._session, prefix=self._prefix, pattern=self._pattern, timeout_s=1.0):
            if name in in_use:
                continue
            try:
                replacement = self._connect(name)
            except TransportError:
                continue
            old = self.envs[index]
            _log.warning("replacing dead node %r by %r (env %d): %s", old.node, name, index, error)
            old.close()
            self.envs[index] = replacement
            return True
        return False

    # -- VecEnv API ----------------------------------------------------------------------------------
    def reset(self) -> npt.NDArray[np.float32]:
        observations = []
        for i, env in enumerate(self.envs):
            obs, self.reset_infos[i] = env.reset(seed=self._seeds[i], options=self._options[i] or None)
            observations.append(obs)
        self._seeds = [None] * self.num_envs
        self._options = [{} for _ in range(self.num_envs)]
        self._last_obs = observations
        return np.stack(observations)

    def step_async(self, actions: Any) -> None:
        self._actions = actions

    def step_wait(
        self,
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.bool_], list[dict[str, Any]]]:
        actions = self._actions
        failed: dict[int, TransportError] = {}
        for i, env in enumerate(self.envs):  # all actions out first: the nodes step in parallel
            try:
                env.send(actions[i])
            except TransportError as exc:
                failed[i] = exc
        results: list[Any] = [None] * self.num_envs
        for i, env in enumerate(self.envs):
            if i not in failed:
                try:
                    results[i] = env.receive()
                except TransportError as exc:
                    failed[i] = exc
        for i, error in failed.items():
            results[i] = self._dead_node_result(i, error)
        return self._collect(results)

    def _dead_node_result(self, index: int, error: TransportError) -> tuple[Any, ...]:
        old = self.envs[index].node
        if not self._replace(index, error):
            raise error
        info = {"node_replaced": {"dead": old, "new": self.envs[index].node, "error": str(error)}}
        return self._last_obs[index], 0.0, False, True, info

    def _collect(self, results: list[Any]) -> tuple[Any, Any, Any, list[dict[str, Any]]]:
        observations, rewards, dones, infos = [], [], [], []
        for i, (last_obs, reward, terminated, truncated, info) in enumerate(results):
            done = terminated or truncated
            obs = last_obs
            if done:
                info["terminal_observation"] = last_obs
                info["TimeLimit.truncated"] = truncated and not terminated
                obs, self.reset_infos[i] = self._reset_one(i)
            observations.append(obs)
            rewards.append(reward)
            dones.append(done)
            infos.append(info)
        self._last_obs = observations
        return (
            np.stack(observations),
            np.asarray(rewards, dtype=np.float32),
            np.asarray(dones, dtype=bool),
            infos,
        )

    def _reset_one(self, index: int) -> tuple[Any, dict[str, Any]]:
        try:
            return self.envs[index].reset()
        except TransportError as exc:
            if not self._replace(index, exc):
                raise
            return self.envs[index].reset()

    def step(self, actions: Any) -> tuple[Any, Any, Any, list[dict[str, Any]]]:
        self.step_async(actions)
        return self.step_wait()

    def close(self) -> None:
        for env in getattr(self, "envs", []):
            env.close()
        self.envs = []
        if self._own_session and getattr(self, "_session", None) is not None:
            self._session.close()
            self._session = None

    def seed(self, seed: int | None = None) -> list[int | None]:
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        self._seeds = [seed + i for i in range(self.num_envs)]
        return list(self._seeds)

    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        if options is None:
            options = {}
        self._options = list(options) if isinstance(options, list) else [dict(options) for _ in self.envs]

    def _indices(self, indices: int | Iterable[int] | None) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices: int | Iterable[int] | None = None) -> list[Any]:
        return [getattr(self.envs[i], attr_name) for i in self._indices(indices)]

    def has_attr(self, attr_name: str) -> bool:
        return hasattr(self.envs[0], attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: int | Iterable[int] | None = None) -> None:
        for i in self._indices(indices):
            setattr(self.envs[i], attr_name, value)

    def env_method(
        self, method_name: str, *args: Any, indices: int | Iterable[int] | None = None, **kwargs: Any
    ) -> list[Any]:
        return [getattr(self.envs[i], method_name)(*args, **kwargs) for i in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: int | Iterable[int] | None = None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> list[None]:
        return [None for _ in self.envs]

    def render(self, mode: str | None = None) -> None:
        return None

    @property
    def unwrapped(self) -> RemoteVecEnv:
        return self

    def getattr_recursive(self, name: str) -> Any:
        return getattr(self, name)

    def getattr_depth_check(self, name: str, already_found: bool) -> str | None:
        return (
            f"{type(self).__module__}.{type(self).__name__}"
            if hasattr(self, name) and already_found
            else None
        )


def _register_with_sb3() -> None:
    """Make ``isinstance(remote_vec_env, VecEnv)`` true in SB3, without importing SB3 here."""
    module = sys.modules.get("stable_baselines3.common.vec_env.base_vec_env")
    if module is not None:
        module.VecEnv.register(RemoteVecEnv)
