"""Evaluation recordings: ``RecordMcap`` records any fmu-bridge env into one MCAP file per run.

The file uses the ``ros2`` profile with standard ROS 2 Jazzy messages (topics and the
recording clock: :mod:`bridge.recording.meta`), so rosbags, ``ros2 bag``, Foxglove and Rerun
read it. A step only keeps its values (as bytes, well under a microsecond); every ~250 steps
and at episode ends they are packed into MCAP records at once (:mod:`bridge.recording.block`).
The file is written as ``NAME.mcap.part``, flushed at every episode end, and renamed to
``NAME.mcap`` by ``close()`` (also called by ``env.close()`` and at interpreter exit).

    env = record_env(FmuEnv("experiment.yaml"), agent="ppo-cartpole.zip")
    ...                      # reset/step as usual
    env.close()              # -> recordings/<experiment>-<time>.mcap
"""

from __future__ import annotations

import atexit
import datetime
import logging
import os
import re
import struct
import unicodedata
import weakref
from array import array
from collections.abc import Callable
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from bridge.errors import ConfigError
from bridge.net.ros2 import cdr
from bridge.plant.base import Plant
from bridge.recording import meta
from bridge.recording.writer import FixedMessage, McapWriter, StepBlock
from bridge.task.core import Task

_log = logging.getLogger(__name__)
STEP_TOPICS = [meta.ACTIONS, meta.AGENT_ACTION, meta.OBSERVATIONS, meta.REWARD, meta.OUTPUTS]


def _as_list(action: Any) -> Any:
    """A copy of a Box/MultiDiscrete action (the agent may reuse its array)."""
    return action.tolist() if action.__class__ is np.ndarray else np.asarray(action).tolist()


def _float_rows(values: list[Any], n: int) -> Any:
    """``n`` rows of float64 from a flat list of numbers (``np.asarray`` for anything else)."""
    try:
        flat = np.frombuffer(array("d", values))
    except (TypeError, ValueError):  # not plain numbers (a 0-d array or such): numpy decides
        flat = np.asarray(values, dtype=np.float64).reshape(-1)
    return flat.reshape(n, -1)


class RecordMcap(gym.Wrapper[Any, Any, Any, Any]):
    """Records an ``FmuEnv`` or ``RemoteFmuEnv`` (anything with ``.task`` and their ``info``).

    Args:
        env: the env to record.
        path: the recording's file name (``.mcap``); ``.part`` is appended while it is written.
        agent: what acts (a model file, a policy name): stored in the metadata.
        seed: the run's seed, if known up front (the seed of every reset is in the events).
        chunk_size: uncompressed bytes per MCAP chunk (at most this is lost to a crash).
        compression: of the chunks, ``zstd`` or ``none``.
        overwrite: replace an existing recording at ``path``.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        path: str | Path,
        *,
        agent: str | None = None,
        seed: int | None = None,
        chunk_size: int = 128 * 1024,
        compression: str = "zstd",
        overwrite: bool = False,
    ) -> None:
        super().__init__(env)
        task, plant = getattr(env.unwrapped, "task", None), getattr(env.unwrapped, "plant", None)
        if not isinstance(task, Task) or not isinstance(plant, Plant):
            raise ConfigError(
                f"RecordMcap records fmu-bridge envs (a Task over a Plant: FmuEnv, RemoteFmuEnv); "
                f"{type(env.unwrapped).__name__} has no .task and .plant to name its signals"
            )
        self.task, self._plant = task, plant
        self._sampling_ns = round(task.timing.sampling_time_s * 1e9)
        obs_size = int(np.prod(env.observation_space.shape or (0,)))
        names = {
            meta.OBSERVATIONS: meta.observation_names(task, obs_size),
            meta.ACTIONS: list(task.input_names),
            meta.AGENT_ACTION: meta.action_names(task, env.action_space),
            meta.OUTPUTS: list(task.output_names),
        }
        components = meta.component_names(plant)  # a system of FMUs: each component's outputs
        self._component_topics = [meta.component_topic(c) for c in components]
        self._component_sizes = np.cumsum([len(v) for v in components.values()])[:-1].tolist()
        names.update(zip(self._component_topics, components.values()))
        topics = [*STEP_TOPICS, *self._component_topics]
        self.writer = writer = McapWriter(
            path, chunk_size=chunk_size, compression=compression, overwrite=overwrite
        )
        try:
            self.channels = ch = meta.open_channels(writer, [*topics, meta.SCENARIO, meta.EVENTS], names)
            self._layouts = {t: cdr.JointStateLayout.of(n) for t, n in names.items()}
            self._scenario_layouts: dict[tuple[str, ...], cdr.JointStateLayout] = {}
            slot = {meta.ACTIONS: 0, meta.AGENT_ACTION: 0}
            self._block = StepBlock(
                [FixedMessage(ch[t], slot.get(t, 1), self._layouts.get(t)) for t in topics]
            )
            meta.write_run_metadata(writer, self._run_info(agent, seed), task.experiment)
        except BaseException:
            writer.close()
            raise
        self._inputs = task.applied_inputs  # the list Task.action_to_inputs fills: the applied input values
        self._discrete = isinstance(env.action_space, gym.spaces.Discrete)
        self._rows: list[tuple[Any, ...]] = []  # per step: time, observation, reward, outputs, components
        self._input_values: list[float] = []  # every step's applied inputs, one after the other
        self._actions: list[Any] = []  # every step's action (its elements, for a Box or MultiDiscrete)
        self._full_block = max(1, chunk_size // self._block.size)  # steps in a whole chunk
        self._rows_per_block = self._full_block
        self._obs_dtype = np.dtype(np.float32)
        self._episode = -1
        self._in_episode = False
        self._clock = meta.RecordingClock(self._sampling_ns)
        self._offset = 0  # recording clock - simulation time, in this episode
        self._t_prev = 0  # simulation time of the last recorded sample, ns
        self._steps = 0
        self._return = 0.0
        self.episodes: list[dict[str, Any]] = []
        self._seeds: list[int | None] = []
        ref = weakref.ref(self)
        self._at_exit = lambda: close_ref(ref)
        atexit.register(self._at_exit)  # a program that never closes the env still gets a whole file

    def _run_info(self, agent: str | None, seed: int | None) -> dict[str, Any]:
        return meta.run_info(type(self.env.unwrapped).__name__, self._plant, self.task.timing, agent, seed)

    # -- Gymnasium API -----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if self._in_episode:
            self._end_episode("reset", False, False, {})
        obs, info = self.env.reset(seed=seed, options=options)
        self._episode += 1
        t_ns = round(info["time_s"] * 1e9)
        self._offset = self._clock.begin(t_ns).offset_ns
        self._t_prev = t_ns
        self._obs_dtype = np.asarray(obs).dtype
        self._in_episode, self._steps, self._return = True, 0, 0.0
        self._seeds.append(seed)
        drawn = dict(info.get("drawn", {}))
        event = {
            "event": "episode_start",
            "episode": self._episode,
            "scenario": info.get("scenario"),
            "seed": seed,
            "time_s": info["time_s"],
            "drawn": drawn,
        }
        spec = self.task.episode
        if spec is not None:
            event["values"] = spec.values
        w, ch, log = self.writer, self.channels, self._clock.next_start_ns
        w.add_message(ch[meta.EVENTS], log, cdr.encode_string(meta.to_json(event)))
        w.add_message(ch[meta.SCENARIO], log, self._scenario(t_ns, drawn))
        messages = [(meta.OBSERVATIONS, obs), (meta.OUTPUTS, info["outputs"])]
        if self._component_topics:
            messages += zip(self._component_topics, self._components_now())
        for topic, values in messages:
            w.add_message(ch[topic], log, self._layouts[topic].pack(t_ns, np.ravel(values).tolist()))
        self._plan_block()
        return obs, info

    def _plan_block(self) -> None:
        """Steps in the next block: as many as fill the current chunk, so an episode's first
        block joins its start messages in one chunk; a whole chunk's worth when less than a
        quarter of one is left (that block then starts the next chunk)."""
        fit = self.writer.room // self._block.size
        self._rows_per_block = fit if fit >= max(1, self._full_block // 4) else self._full_block

    def _scenario(self, t_ns: int, drawn: dict[str, Any]) -> bytes:
        """The scenario message: through the layout of its names (the same every episode,
        mostly: built once by rosbags), or by rosbags itself for values that are not one float
        per name."""
        names = tuple(map(str, drawn))
        layout = self._scenario_layouts.get(names)
        if layout is None:
            layout = self._scenario_layouts[names] = cdr.JointStateLayout.of(names)
        try:
            return layout.pack(t_ns, drawn.values())
        except (struct.error, TypeError):
            return cdr.encode_joint_state(t_ns, names, list(drawn.values()))

    def _components_now(self) -> list[Any]:
        """Each component's output values now (a system of FMUs), split from one flat array."""
        values = self._plant.component_values()
        return np.split(np.asarray(values, dtype=np.float64), self._component_sizes)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        result = self.env.step(action)
        obs, reward, terminated, truncated, info = result
        # Keep the step's values now (bytes, copies); pack them in bulk later (bridge.recording.block).
        # Inputs and actions go into flat lists (the same count every step): a block turns those
        # into arrays several times faster than a tuple of per-step lists.
        self._rows.append(
            (
                info["time_s"],
                obs.tobytes(),
                reward,
                info["outputs"].tobytes(),
                self._plant.component_values().tobytes() if self._component_topics else b"",
            )
        )
        self._input_values += self._inputs
        if self._discrete:
            self._actions.append(action)
        else:  # a copy (the agent may reuse its array)
            self._actions += _as_list(action)
        if terminated or truncated:
            self._end_episode(info.get("reason"), terminated, truncated, info)
        elif len(self._rows) >= self._rows_per_block:
            self._pack_rows()
        return result

    def _pack_rows(self) -> None:
        rows, inputs, actions = self._rows, self._input_values, self._actions
        if not rows:
            return
        self._rows, self._input_values, self._actions = [], [], []
        n = len(rows)
        times, observations, rewards, outputs, components = zip(*rows)
        # array("d", ...) turns Python numbers into a buffer several times faster than np.asarray
        t_ns = np.round(np.frombuffer(array("d", times)) * 1e9).astype(np.int64)
        before = np.concatenate(([self._t_prev], t_ns[:-1]))  # actions are stamped at t_k
        self._t_prev = int(t_ns[-1])
        values = [
            np.frombuffer(array("d", inputs)).reshape(n, len(inputs) // n),
            _float_rows(actions, n),
            np.frombuffer(b"".join(observations), dtype=self._obs_dtype).reshape(n, -1).astype(np.float64),
            np.frombuffer(array("d", rewards)),
            np.frombuffer(b"".join(outputs), dtype=np.float64).reshape(n, -1),
        ]
        if self._component_topics:
            flat = np.frombuffer(b"".join(components), dtype=np.float64).reshape(n, -1)
            values += np.split(flat, self._component_sizes, axis=1)
        offset = self._offset
        self.writer.add_steps(self._block, [(before + offset, before), (t_ns + offset, t_ns)], values)
        self._steps += n
        self._return = float(sum(rewards, self._return))  # sequential, as a per-step sum would be
        self._plan_block()

    def _end_episode(
        self, reason: str | None, terminated: bool, truncated: bool, info: dict[str, Any]
    ) -> None:
        self._pack_rows()
        log = self._t_prev + self._offset
        event = {
            "event": "episode_end",
            "episode": self._episode,
            "steps": self._steps,
            "return": self._return,
            "reason": reason,
            "terminated": bool(terminated),
            "truncated": bool(truncated),
            "time_s": self._t_prev / 1e9,
        }
        if "fmu_error" in info:
            event["fmu_error"] = info["fmu_error"]
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
                    self._end_episode("closed", False, False, {})
                self.writer.add_metadata("run_summary", self._summary())
                path = self.writer.close()
                _log.info("recording saved: %s", path)
        finally:
            super().close()

    def _summary(self) -> dict[str, str]:
        returns = [e["return"] for e in self.episodes]
        return {
            "episodes": str(len(self.episodes)),
            "steps": str(sum(e["steps"] for e in self.episodes)),
            "returns": meta.to_json(returns),
            "seeds": meta.to_json(self._seeds),
            "mean_return": meta.to_json(float(np.mean(returns)) if returns else None),
        }

    @property
    def path(self) -> Path:
        """The finished file's path (``.part`` is appended while recording)."""
        return self.writer.path


def close_ref(ref: weakref.ReferenceType[Any]) -> None:
    """At interpreter exit, finish the recording of a recorder the program forgot to close."""
    recorder = ref()
    if recorder is not None:
        try:
            recorder.close()
        except Exception as exc:  # at exit: report, never raise
            _log.error("finishing the recording failed: %s", exc)


def slug(text: str) -> str:
    """``text`` as a file name that needs no quoting: letters, digits, ``.``, ``_`` and ``-`` kept,
    every other run of characters (spaces, ``:``, ``/``) one ``-`` (``"ball tty" -> "ball-tty"``);
    a sign is kept, so ``constant:-10`` and ``constant:10`` stay apart."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-.") or "run"


def default_run_name(env: gym.Env[Any, Any]) -> str:
    experiment = getattr(getattr(env.unwrapped, "task", None), "experiment", None)
    name = getattr(experiment, "name", "run")
    return f"{name}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}"


MAX_RUN_NAME_CHARS = 150  # with "-<counter>.mcap.part" well within a file name's 255 bytes


def check_run_name(name: str, folder: Path) -> None:
    """Raise ConfigError unless ``name`` is one plain file name: no separator, not ``.`` or ``..``,
    no control, format (bidirectional) or unassigned character, at most MAX_RUN_NAME_CHARS long;
    so the recording lands in ``folder`` under a name that reads as what it is."""
    odd = sorted({c for c in name if unicodedata.category(c)[0] in "CZ" and c != " "})
    problem = (
        f"{len(name):,} characters, at most {MAX_RUN_NAME_CHARS} are allowed"
        if len(name) > MAX_RUN_NAME_CHARS
        else "a path separator"
        if "/" in name or "\\" in name or os.sep in name
        else "no file name"
        if name in ("", ".", "..")
        else f"the characters {''.join(odd)!a}"
        if odd
        else ""
    )
    if problem:
        shown = ascii(name if len(name) <= 60 else name[:57] + "...")
        raise ConfigError(
            f"recording name {shown} has {problem}; give a plain file name (letters, digits, '.', "
            f"'_', '-') so the recording stays in the recordings folder [{folder}]"
        )


def free_path(folder: Path, run_name: str | None, default: Callable[[], str]) -> Path:
    """``folder/<run_name>.mcap`` (``run_name`` checked, else ``default()``; made a plain file name by
    :func:`slug`), with ``-1``, ``-2``, ... added while that file or its ``.part`` exists."""
    if run_name:
        check_run_name(run_name, folder)  # a path, '..' or control characters: refused, not mangled
    base = slug(run_name or default())
    path = folder / f"{base}.mcap"
    counter = 1
    while path.exists() or path.with_name(path.name + ".part").exists():
        path = folder / f"{base}-{counter}.mcap"
        counter += 1
    return path


def record_env(
    env: gym.Env[Any, Any],
    directory: str | Path = "recordings",
    run_name: str | None = None,
    agent: str | None = None,
    *,
    seed: int | None = None,
    chunk_size: int = 128 * 1024,
    compression: str = "zstd",
) -> RecordMcap:
    """Wrap ``env`` to record into ``directory/<run_name>.mcap`` (a free name is chosen).

    ``run_name`` defaults to ``<experiment>-<local time>``, made a plain file name by :func:`slug`;
    ``agent`` and ``seed`` go into the
    metadata (every episode's own seed is in its start event).
    """
    path = free_path(Path(directory), run_name, lambda: default_run_name(env))
    return RecordMcap(env, path, agent=agent, seed=seed, chunk_size=chunk_size, compression=compression)
