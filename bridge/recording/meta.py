"""What every fmu-bridge recording holds besides messages: topics, schemas, metadata.

Topics (one channel each; all ROS 2 Jazzy standard types, so ``ros2 bag``, rosbags, Foxglove
and Rerun read them without our code):

=================  ============================  ============================================
topic              type                          content
=================  ============================  ============================================
``/observations``  ``sensor_msgs/msg/JointState``  what the agent saw (names from the task)
``/actions``       ``sensor_msgs/msg/JointState``  FMU input values applied over the sample
``/agent_action``  ``sensor_msgs/msg/JointState``  the raw action the agent returned
``/reward``        ``std_msgs/msg/Float64``        reward of the step
``/outputs``       ``sensor_msgs/msg/JointState``  unscaled FMU outputs
``/scenario``      ``sensor_msgs/msg/JointState``  the episode's randomly drawn values
``/events``        ``std_msgs/msg/String``         JSON: episode start/end, FMU errors, rejects
=================  ============================  ============================================

A system of FMUs adds ``/components/<component>/outputs`` (``sensor_msgs/msg/JointState``) per
component: every output of that component (and any other variable of it the task reads), by
its own name, stamped like ``/outputs``. Several agents in one system record each agent's
``/observations``, ``/actions``, ``/agent_action`` and ``/reward`` under ``/agents/<agent>``
(:mod:`bridge.recording.agents_recorder`).

Recording clock: MCAP log and publish times (ns) are simulation time shifted per episode:
episode ``e`` starts one sampling period after episode ``e-1`` ended, so several episodes
in one file never overlap and the file's timeline reads like one continuous run. Header
stamps keep the simulation time within the episode. Actions are stamped at the start of
their sample (``t_k``), everything a step produces at its end (``t_k+1``).
"""

from __future__ import annotations

import datetime
import json
import platform
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from typing import Any

import gymnasium as gym
import yaml

from bridge.net.ros2 import cdr
from bridge.plant.base import Plant
from bridge.recording.writer import McapWriter

OBSERVATIONS = "/observations"
ACTIONS = "/actions"
AGENT_ACTION = "/agent_action"
REWARD = "/reward"
OUTPUTS = "/outputs"
SCENARIO = "/scenario"
EVENTS = "/events"
TOPIC_TYPES = {
    OBSERVATIONS: cdr.JOINT_STATE,
    ACTIONS: cdr.JOINT_STATE,
    AGENT_ACTION: cdr.JOINT_STATE,
    REWARD: cdr.FLOAT64,
    OUTPUTS: cdr.JOINT_STATE,
    SCENARIO: cdr.JOINT_STATE,
    EVENTS: cdr.STRING,
}
COMPONENTS = "/components/"
AGENTS = "/agents/"  # several agents in one system: /agents/<agent>/<observations|actions|...>


def component_topic(component: str) -> str:
    """The topic of one component's outputs in a recording of a system of FMUs."""
    return f"{COMPONENTS}{component}/outputs"


def component_names(plant: Plant) -> dict[str, list[str]]:
    """The outputs of each component of a system plant (``Plant.component_outputs``), else {}."""
    return {name: list(values) for name, values in plant.component_outputs().items()}


def topic_type(topic: str) -> str:
    if topic.startswith(AGENTS):  # /agents/<agent>/<kind>: the single agent's type of that kind
        return TOPIC_TYPES["/" + topic.rsplit("/", 1)[-1]]
    return cdr.JOINT_STATE if topic.startswith(COMPONENTS) else TOPIC_TYPES[topic]


RECORDING_CLOCK = (
    "log_time = simulation time + a per-episode offset: each episode starts one sampling period "
    "after the previous one ended; header stamps = simulation time within the episode"
)
PACKAGES = (
    "fmu-bridge",
    "fmpy",
    "gymnasium",
    "numpy",
    "eclipse-zenoh",
    "mcap",
    "rosbags",
    "stable-baselines3",
    "torch",
)


INT64_MAX = (1 << 63) - 1


@dataclass
class EpisodeClock:
    """One episode on the recording clock: ``log time = simulation time + offset_ns``."""

    offset_ns: int
    last_ns: int  # the latest log time written in the episode

    def log_time(self, sim_time_ns: int) -> int | None:
        """The log time of ``sim_time_ns``, or None if it falls outside ``0 .. 2^63-1``."""
        log = sim_time_ns + self.offset_ns
        return log if 0 <= log <= INT64_MAX else None

    def place(self, sim_time_ns: int) -> int | None:
        """:meth:`log_time`, counted as written in the episode."""
        log = self.log_time(sim_time_ns)
        if log is not None:
            self.last_ns = max(self.last_ns, log)
        return log


class RecordingClock:
    """The recording clock (see the module docstring), shared by every recorder.

    ``begin(sim_time_ns)`` starts an episode one sampling period after the previous one ended
    (at 0 for the first); ``end(last_ns)`` closes one whose latest log time was ``last_ns``.
    """

    def __init__(self, sampling_ns: int) -> None:
        self.sampling_ns = sampling_ns
        self.next_start_ns = 0

    def begin(self, sim_time_ns: int) -> EpisodeClock:
        return EpisodeClock(offset_ns=self.next_start_ns - sim_time_ns, last_ns=self.next_start_ns)

    def end(self, last_ns: int) -> None:
        self.next_start_ns = max(self.next_start_ns, last_ns + self.sampling_ns)


def observation_names(task: Any, size: int) -> list[str]:
    """Names of the observation elements (``name[t-1]`` for older history frames)."""
    names = list(task.observer.names)
    history = size // len(names) if names and size % len(names) == 0 else 0
    if history == 1:
        return names
    if history > 1:
        return [f"{n}[t-{history - 1 - h}]" if h < history - 1 else n for h in range(history) for n in names]
    return [f"obs[{i}]" for i in range(size)]


def action_names(task: Any, space: gym.Space[Any]) -> list[str]:
    """Names of the raw action's elements: the driven inputs, or ``index`` for a Discrete space."""
    if isinstance(space, gym.spaces.Discrete):
        return ["index"]
    return list(task.action_inputs)


def package_versions() -> dict[str, str]:
    """Versions of the packages a result depends on (from their metadata: nothing is imported)."""
    versions = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            continue
    return versions


def to_json(value: Any) -> str:
    return _ENCODER.encode(value)


def _jsonable(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    return str(value)


# One encoder for every event (json.dumps with options builds a new one per call).
_ENCODER = json.JSONEncoder(separators=(",", ":"), default=_jsonable, allow_nan=True)


def config_yaml(experiment: Any) -> str:
    """The experiment (after version resolution) as YAML."""
    return str(yaml.safe_dump(experiment.model_dump(mode="json"), sort_keys=False))


@dataclass
class Channels:
    """Channel ids of the standard topics in one writer."""

    ids: dict[str, int]

    def __getitem__(self, topic: str) -> int:
        return self.ids[topic]


def open_channels(writer: McapWriter, topics: list[str], names: dict[str, list[str]]) -> Channels:
    """Register the schemas and the channels of ``topics`` (JointState channels list their names)."""
    ids = {}
    for topic in topics:
        msgtype = topic_type(topic)
        schema_id = writer.add_schema(msgtype, "ros2msg", cdr.schema_text(msgtype).encode())
        meta = {"offered_qos_profiles": ""}
        if topic in names:
            meta["names"] = to_json(list(names[topic]))
        ids[topic] = writer.add_channel(topic, schema_id, "cdr", meta)
    return Channels(ids)


def run_info(
    env_name: str, plant: Plant, timing: Any, agent: str | None, seed: int | None, **extra: Any
) -> dict[str, Any]:
    """The run's ``fmu_bridge`` metadata (before :func:`write_run_metadata` adds the experiment's):
    the env, the plant and its FMU, the agent (``extra`` follows it), the seed and the timing."""
    origin = plant.provenance()
    return {
        "env": env_name,
        "plant": plant.name,
        "node": origin["node"],
        "agent": str(agent) if agent else "",
        **extra,
        "seed": "" if seed is None else str(seed),
        "fmu": origin["fmu"],
        "fmu_sha256": origin["fmu_sha256"],
        "step_size_s": timing.step_size_s,
        "sampling_time_s": timing.sampling_time_s,
        "start_time_s": timing.start_time_s,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }


def write_run_metadata(writer: McapWriter, run: dict[str, Any], experiment: Any = None) -> None:
    """The ``fmu_bridge`` and ``versions`` metadata records, and the experiment file attached."""
    entries = {key: value if isinstance(value, str) else to_json(value) for key, value in run.items()}
    entries["recording_clock"] = RECORDING_CLOCK
    if experiment is not None:
        entries["config"] = config_yaml(experiment)
        entries["experiment"] = experiment.name
        entries["version"] = experiment.version
    writer.add_metadata("fmu_bridge", entries)
    writer.add_metadata("versions", package_versions())
    source = getattr(experiment, "source", None)
    if source is not None and source.is_file():
        writer.add_attachment(source.name, "application/yaml", source.read_bytes())
