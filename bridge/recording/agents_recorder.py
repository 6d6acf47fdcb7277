"""Recording several agents of one system: ``RecordAgents`` wraps a PettingZoo parallel env over a
system (``bridge.env.multi_agent.SystemParallelEnv``) and records it into one MCAP file.

The file is an fmu-bridge recording like :class:`~bridge.recording.env_recorder.RecordMcap`'s (the
``ros2`` profile, standard ROS 2 messages, the same recording clock, metadata and ``/events``), with
each agent's streams under its own name instead of the single agent's:

=================================  ============================  ===================================
topic                              type                          content
=================================  ============================  ===================================
``/agents/<agent>/observations``   ``sensor_msgs/msg/JointState``  what the agent saw
``/agents/<agent>/actions``        ``sensor_msgs/msg/JointState``  its FMU inputs applied over the sample
``/agents/<agent>/agent_action``   ``sensor_msgs/msg/JointState``  the raw action it returned (-1..1)
``/agents/<agent>/reward``         ``std_msgs/msg/Float64``        its reward of the step
``/components/<c>/outputs``        ``sensor_msgs/msg/JointState``  every output of each component
=================================  ============================  ===================================

``episode_end`` events carry each agent's return (``returns``) and their sum (``return``).

    env = RecordAgents(SystemParallelEnv("agents.yaml"), "recordings/agents.mcap")
    ...                      # reset/step as usual (PettingZoo Parallel API)
    env.close()              # -> recordings/agents.mcap

Recording does not import the env: any parallel env with the system's ``plant``, its
``experiment`` (whose ``system.agents`` name each agent's inputs and observations) and
``applied_inputs`` (each agent's FMU input values of the last step) can be recorded.
"""

from __future__ import annotations

import atexit
import datetime
import logging
import weakref
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bridge.errors import ConfigError
from bridge.net.ros2 import cdr
from bridge.plant.base import Plant
from bridge.recording import meta
from bridge.recording.env_recorder import close_ref, free_path
from bridge.recording.writer import McapWriter

_log = logging.getLogger(__name__)
KINDS = ("observations", "actions", "agent_action", "reward")


class RecordAgents:
    """Records ``env`` (a parallel env over a system, several agents) into ``path`` (``.mcap``).

    Args:
        env: the parallel env to record (see the module docstring).
        path: the recording's file name; ``.part`` is appended while it is written.
        agent: what acts (a recipe, a policy folder): stored in the metadata.
        seed: the run's seed, if known up front (every reset's seed is in its start event).
        overwrite: replace an existing recording at ``path``.
    """

    def __init__(
        self,
        env: Any,
        path: str | Path,
        *,
        agent: str | None = None,
        seed: int | None = None,
        chunk_size: int = 128 * 1024,
        compression: str = "zstd",
        overwrite: bool = False,
    ) -> None:
        plant, experiment = getattr(env, "plant", None), getattr(env, "experiment", None)
        section = getattr(experiment, "system", None)
        if not isinstance(plant, Plant) or section is None or not getattr(section, "agents", None):
            raise ConfigError(
                f"RecordAgents records a parallel env over a system with agents (SystemParallelEnv); "
                f"{type(env).__name__} has no .plant and .experiment with system.agents"
            )
        self.env, self._plant, self.experiment = env, plant, experiment
        self._specs = dict(section.agents)
        names: dict[str, list[str]] = {}
        for name, spec in self._specs.items():
            names[topic(name, "observations")] = list(spec.observations)
            names[topic(name, "actions")] = list(spec.inputs)
            names[topic(name, "agent_action")] = list(spec.inputs)
        components = meta.component_names(plant)
        self._component_topics = [meta.component_topic(c) for c in components]
        self._component_sizes = np.cumsum([len(v) for v in components.values()])[:-1].tolist()
        names.update(zip(self._component_topics, components.values()))
        agent_topics = [topic(n, kind) for n in self._specs for kind in KINDS]
        self.writer = writer = McapWriter(
            path, chunk_size=chunk_size, compression=compression, overwrite=overwrite
        )
        try:
            topics = [*agent_topics, *self._component_topics, meta.EVENTS]
            self.channels = meta.open_channels(writer, topics, names)
            self._layouts = {t: cdr.JointStateLayout.of(n) for t, n in names.items()}
            meta.write_run_metadata(writer, self._run_info(agent, seed), experiment)
        except BaseException:
            writer.close()
            raise
        self._clock = meta.RecordingClock(round(plant.timing.sampling_time_s * 1e9))
        self._offset = 0
        self._t_ns = 0  # simulation time of the last recorded sample
        self._episode = -1
        self._in_episode = False
        self._steps = 0
        self._returns: dict[str, float] = {}
        self._seeds: list[int | None] = []
        self.episodes: list[dict[str, Any]] = []
        ref = weakref.ref(self)
        self._at_exit = lambda: close_ref(ref)
        atexit.register(self._at_exit)

    def _run_info(self, agent: str | None, seed: int | None) -> dict[str, Any]:
        return meta.run_info(
            type(self.env).__name__, self._plant, self._plant.timing, agent, seed, agents=list(self._specs)
        )

    # -- the PettingZoo Parallel API, passed through ------------------------------------------------
    @property
    def unwrapped(self) -> Any:
        return self.env.unwrapped

    def __getattr__(self, name: str) -> Any:  # the rest of the env's API (num_agents, state, ...)
        if name.startswith("_") or name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def possible_agents(self) -> list[str]:
        return list(self.env.possible_agents)

    @property
    def agents(self) -> list[str]:
        return list(self.env.agents)

    @property
    def metadata(self) -> dict[str, Any]:
        return dict(self.env.metadata)

    def observation_space(self, agent: str) -> Any:
        return self.env.observation_space(agent)

    def action_space(self, agent: str) -> Any:
        return self.env.action_space(agent)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        if self._in_episode:
            self._end_episode("reset", False, False)
        observations, infos = self.env.reset(seed=seed, options=options)
        self._episode += 1
        self._t_ns = t_ns = round(self._plant.time_s * 1e9)
        self._offset = self._clock.begin(t_ns).offset_ns
        self._in_episode, self._steps = True, 0
        self._returns = dict.fromkeys(self._specs, 0.0)
        self._seeds.append(seed)
        event = {"event": "episode_start", "episode": self._episode, "seed": seed, "time_s": t_ns / 1e9}
        log = self._clock.next_start_ns
        self.writer.add_message(self.channels[meta.EVENTS], log, cdr.encode_string(meta.to_json(event)))
        for name, values in observations.items():
            self._joint(topic(name, "observations"), log, t_ns, values)
        self._components(log, t_ns)
        return observations, infos

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, Any]]:
        before_ns = self._t_ns
        observations, rewards, terminated, truncated, infos = self.env.step(actions)
        t_ns = self._t_ns = round(self._plant.time_s * 1e9)
        applied = self.env.applied_inputs
        for name, action in actions.items():  # actions are stamped at the start of their sample
            self._joint(topic(name, "agent_action"), before_ns + self._offset, before_ns, action)
            self._joint(topic(name, "actions"), before_ns + self._offset, before_ns, applied[name])
        log = t_ns + self._offset
        for name, values in observations.items():
            self._joint(topic(name, "observations"), log, t_ns, values)
        for name, reward in rewards.items():
            channel = self.channels[topic(name, "reward")]
            self.writer.add_message(channel, log, cdr.encode_float64(float(reward)))
            self._returns[name] += float(reward)
        self._components(log, t_ns)
        self._steps += 1
        if any(terminated.values()) or any(truncated.values()):
            reason = "terminated" if any(terminated.values()) else "time"
            self._end_episode(reason, any(terminated.values()), any(truncated.values()))
        return observations, rewards, terminated, truncated, infos

    def _joint(self, name: str, log_ns: int, stamp_ns: int, values: Any) -> None:
        payload = self._layouts[name].pack(stamp_ns, np.asarray(values, dtype=np.float64).ravel().tolist())
        self.writer.add_message(self.channels[name], log_ns, payload)

    def _components(self, log_ns: int, t_ns: int) -> None:
        if not self._component_topics:
            return
        flat = np.asarray(self._plant.component_values(), dtype=np.float64)
        for name, values in zip(self._component_topics, np.split(flat, self._component_sizes)):
            self._joint(name, log_ns, t_ns, values)

    def _end_episode(self, reason: str, terminated: bool, truncated: bool) -> None:
        log = self._t_ns + self._offset
        event = {
            "event": "episode_end",
            "episode": self._episode,
            "steps": self._steps,
            "return": float(sum(self._returns.values())),
            "returns": dict(self._returns),
            "reason": reason,
            "terminated": bool(terminated),
            "truncated": bool(truncated),
            "time_s": self._t_ns / 1e9,
        }
        self.writer.add_message(self.channels[meta.EVENTS], log, cdr.encode_string(meta.to_json(event)))
        self.episodes.append(event)
        self._in_episode = False
        self._clock.end(log)
        self.writer.flush()

    def close(self) -> None:
        """Finish the recording (summary, footer, rename from ``.part``), then close the env."""
        atexit.unregister(self._at_exit)
        try:
            if not self.writer.closed:
                if self._in_episode:
                    self._end_episode("closed", False, False)
                returns = {n: [e["returns"][n] for e in self.episodes] for n in self._specs}
                self.writer.add_metadata(
                    "run_summary",
                    {
                        "episodes": str(len(self.episodes)),
                        "steps": str(sum(e["steps"] for e in self.episodes)),
                        "returns": meta.to_json([e["return"] for e in self.episodes]),
                        "agent_returns": meta.to_json(returns),
                        "seeds": meta.to_json(self._seeds),
                    },
                )
                path = self.writer.close()
                _log.info("recording saved: %s", path)
        finally:
            self.env.close()

    @property
    def path(self) -> Path:
        """The finished file's path (``.part`` is appended while recording)."""
        return self.writer.path


def topic(agent: str, kind: str) -> str:
    """The topic of one of an agent's streams (``kind``: observations, actions, agent_action, reward)."""
    return f"{meta.AGENTS}{agent}/{kind}"


def record_agents(
    env: Any,
    directory: str | Path = "recordings",
    run_name: str | None = None,
    agent: str | None = None,
    *,
    seed: int | None = None,
) -> RecordAgents:
    """Wrap ``env`` to record into ``directory/<run_name>.mcap`` (a free name is chosen), as
    :func:`bridge.recording.env_recorder.record_env` does for one agent."""
    experiment = getattr(getattr(env, "experiment", None), "name", "agents")
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = free_path(Path(directory), run_name, lambda: f"{experiment}-{stamp}")
    return RecordAgents(env, path, agent=agent, seed=seed)
