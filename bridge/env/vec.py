"""Vector envs over plants: stable-baselines3's VecEnv interface, plants stepping in parallel.

``PlantVecEnv`` steps N ``FmuEnv`` (any plants): all actions go out first, then all results are
gathered, so plants in other processes or nodes step in parallel and the trainer waits once per
vector step. Episodes auto-reset exactly as SB3 expects: the last observation is in
``infos[i]["terminal_observation"]`` and ``TimeLimit.truncated`` marks truncation.

Errors (``PlantError``: a failed step, a timeout, a dead plant) truncate that env's episode
and reset it (``on_error="truncate"``, the default of every vector env here: one env's error
ends its episode, not the run; the error is in ``infos[i]["plant_error"]``), or stop the run
(``on_error="raise"``). ``RemoteVecEnv`` builds one over nodes found by name
or pattern and, with ``replace_dead=True``, replaces a node that died or hung by a spare.

bridge never imports stable-baselines3: this class implements the VecEnv interface and
registers itself as a virtual subclass of SB3's ``VecEnv`` whenever SB3 is loaded, which is
what SB3's ``isinstance`` checks need.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.env.autoreset import OnError, on_error_mode
from bridge.env.fmu_env import FmuEnv
from bridge.env.remote import RemoteFmuEnv
from bridge.env.sb3_vec import Sb3VecEnv
from bridge.errors import BridgeError, ConfigError, PlantDied, PlantError, StepTimeout
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.sections import REPLACE_WAIT_S
from bridge.net import protocol as proto
from bridge.net.remote import list_nodes
from bridge.net.transport import ZenohOptions, open_session

_log = logging.getLogger(__name__)
Result = tuple[Any, float, bool, bool, dict[str, Any]]


class PlantVecEnv(Sb3VecEnv):
    """N envs stepped together, each over its own plant.

    Args:
        envs: the envs (they share the observation and action spaces); owned from then on.
        on_error: ``"truncate"`` (default) the episode of an env whose plant fails, or ``"raise"``.
    """

    def __init__(self, envs: Sequence[FmuEnv], *, on_error: OnError = "truncate") -> None:
        super().__init__()
        if not envs:
            raise ConfigError("a vector env needs at least one env")
        self.envs: list[FmuEnv] = list(envs)
        self.on_error = on_error_mode(on_error)
        self.num_envs = len(self.envs)
        first = self.envs[0]
        self.observation_space, self.action_space = first.observation_space, first.action_space
        self.render_mode = None
        self.metadata: dict[str, Any] = {"render_modes": []}
        self._seeds: list[int | None] = [None] * self.num_envs
        self._options: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        self.reset_infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        self._actions: Any = None
        self.partial_results: list[Any] = []
        self._last_obs: list[npt.NDArray[np.float32]] = []

    # -- VecEnv API ----------------------------------------------------------------------------------
    def reset(self) -> npt.NDArray[np.float32]:
        observations = []
        for i in range(self.num_envs):
            obs, self.reset_infos[i] = self._reset_one(i, self._seeds[i], self._options[i] or None)
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
        return self._collect(self.step_envs(self._actions))  # type: ignore[arg-type]  # all envs stepped

    def step_envs(self, actions: Any, indices: Sequence[int] | None = None) -> list[Result | None]:
        """Step envs ``indices`` (default: all) with ``actions[i]``: every action goes out before
        any result is awaited; a failed env's result is its last observation, truncated, with
        ``plant_error`` in its info (or the error is raised, as ``on_error`` says). No auto-reset;
        envs not stepped get ``None``."""
        stepped = list(range(self.num_envs)) if indices is None else list(indices)
        failed: dict[int, PlantError] = {}
        for i in stepped:  # all actions out first: the plants step in parallel
            try:
                self.envs[i].send(actions[i])
            except PlantError as exc:
                failed[i] = exc
        results: list[Any] = [None] * self.num_envs
        for i, error in failed.items():
            if self._raises_at_once(error):
                self._failed_result(i, error)
        for i in self._in_answer_order([i for i in stepped if i not in failed]):
            try:
                results[i] = self.envs[i].receive()
            except PlantError as exc:
                if self._raises_at_once(exc):  # reported now, not after a hung env's timeout
                    self._failed_result(i, exc)
                failed[i] = exc
        # the healthy envs' results are in before a failed env is recovered (which may wait for a
        # replacement, or raise: then ``partial_results`` keeps them, None for the failed envs)
        self.partial_results = list(results)
        for i, error in sorted(failed.items()):
            results[i] = self._failed_result(i, error)
        self.partial_results = []
        return results

    def _in_answer_order(self, pending: list[int]) -> Iterable[int]:
        """The envs to receive from, in the order their plants answer (in-process: in order)."""
        return pending

    def _raises_at_once(self, error: PlantError) -> bool:
        """Whether recovering from ``error`` only raises it (then no other result is awaited)."""
        return self.on_error == "raise"

    def _failed_result(self, index: int, error: PlantError) -> Result:
        info = self._recover(index, error)
        info["plant_error"] = str(error)
        return self._last_obs[index], 0.0, False, True, info

    def _recover(self, index: int, error: PlantError) -> dict[str, Any]:
        """What to do about env ``index`` whose plant failed: raise, or go on (info entries)."""
        if self.on_error == "raise":
            raise error
        _log.warning("env %d: episode truncated by a plant error: %s", index, error)
        return {}

    def _collect(self, results: list[Result]) -> tuple[Any, Any, Any, list[dict[str, Any]]]:
        observations, rewards, dones, infos = [], [], [], []
        for i, (last_obs, reward, terminated, truncated, info) in enumerate(results):
            done = terminated or truncated
            obs = last_obs
            if done:
                info["terminal_observation"] = last_obs
                info["TimeLimit.truncated"] = truncated and not terminated
                obs, self.reset_infos[i] = self._reset_one(i)
                if "node_replaced" in self.reset_infos[i]:  # replaced during the auto-reset
                    info.setdefault("node_replaced", self.reset_infos[i]["node_replaced"])
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

    def _reset_one(
        self, index: int, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        try:
            obs, info = self.envs[index].reset(seed=seed, options=options)
        except PlantError as exc:
            return self._reset_failed(index, exc, seed, options)
        if len(self._last_obs) == self.num_envs:
            self._last_obs[index] = obs
        return obs, info

    def _reset_failed(
        self, index: int, error: PlantError, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Env ``index``'s reset failed with ``error``: recover (raise, or a replacement) and reset again."""
        recovered = self._recover(index, error)
        obs, reset_info = self.envs[index].reset(seed=seed, options=options)
        if len(self._last_obs) == self.num_envs:
            self._last_obs[index] = obs
        return obs, {**reset_info, **recovered}

    def close(self) -> None:
        for env in getattr(self, "envs", []):
            env.close()
        self.envs = []

    def seed(self, seed: int | None = None) -> list[int | None]:
        seed = self._new_seed(seed)
        self._seeds = [seed + i for i in range(self.num_envs)]
        return list(self._seeds)

    def set_options(self, options: list[dict[str, Any]] | dict[str, Any] | None = None) -> None:
        if options is None:
            options = {}
        self._options = list(options) if isinstance(options, list) else [dict(options) for _ in self.envs]

    def _attr_targets(self, indices: list[int]) -> list[Any]:
        return [self.envs[i] for i in indices]


class RemoteVecEnv(PlantVecEnv):
    """N remote envs stepped in parallel (one per node).

    Args:
        experiment: the experiment the nodes serve.
        nodes: node names, or a glob pattern (``"worker-*"``) matched against live nodes.
        n_envs: how many envs (default: every listed or matching node); extra matches are spares.
        replace_dead: replace a node that died or stopped answering by a spare (``nodes`` as a
            pattern) or by the same name coming back, and truncate its episode, instead of raising;
            the replacement goes on with the dead env's random generator (a seeded run draws the
            same episodes as one without the replacement).
        replace_wait_s: with ``replace_dead``, how long to wait for a replacement when none is up
            (default 30 s: a node restarted under its name, by hand or by a supervisor, is picked
            up); only then the error is raised (the healthy envs' results of that step are kept
            in ``partial_results``). 0 raises at once.
        on_error: what a failed model step does (``"truncate"``, the default, or ``"raise"``);
            dead and hung nodes are replaced first where ``replace_dead`` allows.
        claim: lease each node as it is taken (a first reset): a node another client holds is
            passed over for the next match, so vector envs drawing on one pool of nodes (e.g. one
            per Ray env runner) never share a node; spares are claimed the same way.
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
        on_error: OnError = "truncate",
        discovery_timeout_s: float = 10.0,
        replace_wait_s: float = REPLACE_WAIT_S,
        claim: bool = False,
    ) -> None:
        self.experiment = as_experiment(experiment)
        self.claim = claim
        self.replace_wait_s = replace_wait_s
        self._any_answer = threading.Event()
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._prefix, self._timeout_s, self.replace_dead = prefix, timeout_s, replace_dead
        self._pattern = nodes if isinstance(nodes, str) else None
        envs: list[FmuEnv] = []
        try:
            if claim:
                envs = self._claim(nodes, n_envs, discovery_timeout_s, envs)
            else:
                for name in self._discover(nodes, n_envs, discovery_timeout_s):
                    envs.append(self._connect(name))
            super().__init__(envs, on_error=on_error)
        except BaseException:
            for env in envs:
                env.close()
            self._close_session()
            raise

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

    def _claim(
        self, nodes: Sequence[str] | str, n_envs: int | None, timeout_s: float, envs: list[FmuEnv]
    ) -> list[FmuEnv]:
        """Connect to and lease ``n_envs`` nodes (default: all listed, or all matching at first
        look), passing over the ones held by others, until the timeout."""
        wanted = n_envs or (len(nodes) if not isinstance(nodes, str) else 0)
        deadline = time.monotonic() + timeout_s
        refused: dict[str, str] = {}
        while True:
            if isinstance(nodes, str):
                names = list_nodes(self._session, prefix=self._prefix, pattern=nodes, timeout_s=1.0)
                wanted = wanted or len(names)
            else:
                names = list(nodes)
            held = {env.node for env in envs if isinstance(env, RemoteFmuEnv)}
            for name in names:
                if len(envs) >= wanted > 0:
                    return envs
                if name in held:
                    continue
                try:
                    envs.append(self._connect(name))
                except BridgeError as exc:
                    refused[name] = str(exc)
            if len(envs) >= wanted > 0:
                return envs
            if time.monotonic() > deadline:
                raise ConfigError(
                    f"RemoteVecEnv could lease {len(envs)} of {wanted or 'at least one'} node(s) matching "
                    f"{nodes!r} under {self._prefix}/ (found {names}; refused: {refused or 'none'}); start "
                    "more with `fmu-bridge node EXPERIMENT --name NAME`"
                )
            time.sleep(0.2)

    def _connect(self, name: str) -> RemoteFmuEnv:
        env = RemoteFmuEnv(
            self.experiment, name, session=self._session, prefix=self._prefix, timeout_s=self._timeout_s
        )
        env.plant.notify_answers(self._any_answer)
        if self.claim:
            try:
                env.reset()  # the lease: refused while another client holds the node
            except BaseException:
                env.close()
                raise
        return env

    def _in_answer_order(self, pending: list[int]) -> Iterable[int]:
        """Nodes in the order they answer: a dead node is reported at once, not after a hung one's timeout."""
        if len(pending) < 2:
            yield from pending
            return
        waiting = list(pending)
        while waiting:
            self._any_answer.clear()
            ready = [i for i in waiting if self.envs[i].plant.answer_ready()]
            if not ready:
                self._any_answer.wait(0.05)
                continue
            for i in ready:
                waiting.remove(i)
                yield i

    def _raises_at_once(self, error: PlantError) -> bool:
        replaceable = isinstance(error, PlantDied | StepTimeout) and self.replace_dead
        return super()._raises_at_once(error) and not replaceable

    def _recover(self, index: int, error: PlantError) -> dict[str, Any]:
        if isinstance(error, PlantDied | StepTimeout) and self.replace_dead:
            old = self.envs[index]
            assert isinstance(old, RemoteFmuEnv)
            if self._replace(index, error):
                return {
                    "node_replaced": {"dead": old.node, "new": self.node_names[index], "error": str(error)}
                }
        return super()._recover(index, error)

    @property
    def node_names(self) -> list[str]:
        return [env.node for env in self.envs if isinstance(env, RemoteFmuEnv)]

    def _replace(self, index: int, error: PlantError) -> bool:
        """Put a live node in place of env ``index``'s: a spare matching the pattern or the same
        name come back, waiting up to ``replace_wait_s``; raise ``error`` if none comes."""
        old = self.envs[index]
        dead = getattr(old, "node", "")
        deadline = time.monotonic() + self.replace_wait_s
        while True:
            replacement = self._live_replacement(dead)
            if replacement is not None:
                new = replacement.node
                _log.warning("replacing dead node %r by %r (env %d): %s", dead, new, index, error)
                # the env's episodes go on from the dead env's generator: a seeded run draws the
                # same episodes whether or not a node was replaced on the way
                replacement.np_random = old.np_random
                old.close()
                self.envs[index] = replacement
                return True
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        if self.replace_wait_s > 0:
            raise PlantDied(
                f"{error}; no replacement for node {dead!r} came within replace_wait_s = "
                f"{self.replace_wait_s:g} s (a spare matching {self._pattern!r} or {dead!r} restarted)",
                plant=getattr(error, "plant", dead),
                detail=getattr(error, "detail", str(error)),
            ) from error
        raise error

    def _reset_one(
        self, index: int, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if not self.replace_dead:
            return super()._reset_one(index, seed, options)
        # a reset that fails on a dead node has drawn its episode already: the replacement draws
        # it again from the same state, so the episodes stay those of an undisturbed run
        env = self.envs[index]
        drawn_from = env.np_random.bit_generator.state
        try:
            return env.reset(seed=seed, options=options)
        except PlantError as exc:
            info = self._recover(index, exc)
            env = self.envs[index]
            env.np_random.bit_generator.state = drawn_from
            obs, reset_info = env.reset(seed=seed, options=options)
            return obs, {**reset_info, **info}

    def _live_replacement(self, dead: str) -> RemoteFmuEnv | None:
        in_use = set(self.node_names) - {dead}
        spares = (
            list_nodes(self._session, prefix=self._prefix, pattern=self._pattern, timeout_s=1.0)
            if self._pattern is not None
            else []
        )
        if dead not in spares:
            spares += list_nodes(self._session, prefix=self._prefix, pattern=dead, timeout_s=1.0)
        for name in sorted(set(spares) - in_use, key=lambda n: (n == dead, n)):  # spares first
            try:
                return self._connect(name)
            except (PlantError, ConfigError, BridgeError):
                continue  # still starting, just died, or taken: try the next, or again later
        return None

    def close(self) -> None:
        super().close()
        self._close_session()

    def _close_session(self) -> None:
        if getattr(self, "_own_session", False) and getattr(self, "_session", None) is not None:
            self._session.close()
            self._session = None
