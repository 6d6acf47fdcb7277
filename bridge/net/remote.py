"""The client side of FMU nodes: ``RemotePlant`` (a node as a plant), ``NodeClient`` and discovery.

``bridge.env.RemoteFmuEnv`` is the one env over a ``RemotePlant``: the Task (actions,
observations, reward, termination, scenarios and all randomness) runs in the env, only the
model runs in the node, so the same seed gives the same trajectory in-process and remote. The
FMU need not exist on this machine: the node reports its variables, and the Task is checked
against them.
"""

from __future__ import annotations

import fnmatch
import logging
import secrets
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

from bridge.errors import (
    FMU_LOG_HEADER,
    BridgeError,
    ConfigError,
    PlantDied,
    StepError,
    StepTimeout,
    TransportError,
)
from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, check_experiment, timing
from bridge.fmu.vocab import info_from_summary
from bridge.net import protocol as proto
from bridge.net.transport import ZenohOptions, open_session, undeclare
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant

_log = logging.getLogger(__name__)


def query_info(session: Any, keys: proto.Keys, timeout_s: float) -> dict[str, Any]:
    """The node's ``info`` reply; TransportError if no node of that name answers in ``timeout_s``."""
    # A query sent before routes exist finds no queryable and returns at once: retry until the
    # timeout, so a just-opened session or a node that is still starting is found.
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        for reply in session.get(keys.info, timeout=max(0.05, min(remaining, 1.0))):
            if reply.ok is not None:
                return proto.decode_json(reply.ok.payload.to_bytes(), f"info of node {keys.node!r}")
        if remaining <= 0:
            break
        time.sleep(min(0.1, max(remaining, 0.0)))
    raise TransportError(
        f"no FMU node named {keys.node!r} answers on {keys.info} within {timeout_s:g} s; "
        f"start one with `fmu-bridge node EXPERIMENT --name {keys.node}` and check the Zenoh endpoints "
        "(`fmu-bridge nodes` lists the live ones)"
    )


class NodeClient:
    """Talks to one node: stamped actions out, the matching outputs frame back.

    The client has a random id, sent with every reset and action, and a liveliness token
    ``<prefix>/<node>/clients/<id>`` that ends the node's lease when this session goes away.
    """

    def __init__(
        self,
        session: Any,
        node: str,
        *,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
    ) -> None:
        self.keys = proto.Keys(prefix, node)
        self.name = node
        self.timeout_s = timeout_s
        self.take_over = take_over
        self.client_id = secrets.randbits(63) | 1
        self.notify: threading.Event | None = None  # set too whenever an answer arrives (vector envs)
        self._session = session
        self._event = threading.Event()
        self._want: tuple[int, int] = (-1, -1)
        self._deadline = 0.0
        self._frame: proto.Frame | None = None
        self.alive = True
        self.description = query_info(session, self.keys, timeout_s)
        self._declared = [
            session.liveliness().declare_token(self.keys.client(self.client_id)),
            self._subscribe_frames(),
            session.liveliness().declare_subscriber(self.keys.alive, self._on_liveliness, history=True),
        ]
        self._pub = session.declare_publisher(self.keys.actions)
        self._declared.append(self._pub)

    def _subscribe_frames(self) -> Any:
        """The node's outputs frames, each handed to ``_on_frame`` on Zenoh's thread."""
        return self._session.declare_subscriber(self.keys.outputs, self._on_frame)

    def _on_frame(self, sample: Any) -> None:
        try:
            frame = proto.decode(sample.payload.to_bytes())
        except TransportError:
            return
        if self._answers(frame):
            self._frame = frame
            self._wake()

    def _answers(self, frame: proto.Frame) -> bool:
        """Whether ``frame`` answers the last action: its step, and not another client's reject."""
        if (frame.episode, frame.step) != self._want:
            return False
        return frame.kind != proto.REJECT or frame.sim_time_ns in (0, self.client_id)

    def _wake(self) -> None:
        self._event.set()
        notify = self.notify
        if notify is not None:
            notify.set()

    def _on_liveliness(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE:
            self.alive = False
            self._wake()  # wake a waiting step at once
            self._lost()
        else:
            self.alive = True

    def _arm(self) -> None:
        """Forget the last answer before the next action is sent."""
        self._frame = None
        self._event.clear()

    def _lost(self) -> None:
        """The node's liveliness token ended (``_wake`` has woken a waiting step)."""

    def send_action(
        self, plant: Plant, episode: int, step: int, inputs: Sequence[float], flags: int = 0
    ) -> None:
        """Publish the action for ``step``; ``flags``: SAVE_STATE or RESTORE_STATE (rollback)."""
        if not self.alive:
            raise self._dead(plant)
        self._arm()
        self._want = (episode, step)
        self._deadline = time.monotonic() + self.timeout_s
        self._pub.put(proto.encode_values(proto.ACTION, episode, step, self.client_id, inputs, flags=flags))

    def ready(self) -> bool:
        """Whether ``wait`` would return (or raise) at once: an answer, a death or the deadline."""
        return self._event.is_set() or time.monotonic() >= self._deadline

    def wait(self, plant: Plant) -> proto.Frame:
        """The outputs frame for the last action; raises if the node died, rejected it or timed out."""
        if not self._answered():
            raise plant.failure(
                StepTimeout,
                f"no answer within {self.timeout_s:g} s",
                f"no outputs for step {self._want[1]} within {self.timeout_s:g} s",
                "the node may be overloaded, hung or unreachable; "
                f"timeout_s sets the limit [{self.keys.base}]",
            )
        frame = self._frame
        if frame is None:
            raise self._dead(plant)
        if frame.kind == proto.REJECT:
            raise TransportError(
                f"{plant.name} rejected step {self._want[1]} of episode {self._want[0]}: {frame.message}"
            )
        return frame

    def _answered(self) -> bool:
        """Block until the answer arrives or the node dies (True), or until the deadline (False)."""
        return self._event.wait(max(0.0, self._deadline - time.monotonic()))

    def _dead(self, plant: Plant, step: int | None = -1) -> PlantDied:
        fields: dict[str, Any] = {} if step == -1 else {"step": step}
        return plant.failure(
            PlantDied,
            "the plant died",
            "the node's liveliness token disappeared",
            f"restart it, or let RemoteVecEnv replace dead nodes [{self.keys.base}]",
            **fields,
        )

    def reset(self, plant: Plant, values: dict[str, Any], inputs: list[float]) -> proto.Frame:
        if not self.alive:
            raise self._dead(plant, step=None)
        episode = plant.episode
        request = proto.encode_json(
            {
                "episode": episode,
                "values": values,
                "inputs": inputs,
                "client": self.client_id,
                "zid": str(self._session.zid()),
                "take_over": self.take_over,
            }
        )
        self._want = (episode, 0)
        start = time.monotonic()
        for reply in self._session.get(self.keys.reset, payload=request, timeout=self.timeout_s):
            if reply.ok is not None:
                return proto.decode(reply.ok.payload.to_bytes())
            raise self._reset_refused(plant, reply.err.payload.to_bytes().decode(errors="replace"))
        if not self.alive or time.monotonic() - start < 0.5 * self.timeout_s:
            # No queryable answered long before the deadline: nothing serves the reset key any more.
            raise plant.failure(
                PlantDied,
                "the plant died",
                "nothing answers on the node's reset key (the node stopped or died)",
                f"restart it, or let RemoteVecEnv replace dead nodes [{self.keys.reset}]",
                step=None,
            )
        raise plant.failure(
            StepTimeout,
            f"no answer within {self.timeout_s:g} s",
            "the reset request got no reply",
            f"the node may be overloaded, hung or unreachable [{self.keys.reset}]",
            step=None,
        )

    def _reset_refused(self, plant: Plant, message: str) -> BridgeError:
        code, _, detail = message.partition(": ")
        if code == "unhealthy":
            return plant.failure(PlantDied, "the plant is unhealthy", detail, "restart the node", step=None)
        return TransportError(f"{plant.name}: the reset was refused ({code}): {detail}")

    def close(self) -> None:
        for entity in reversed(self._declared):
            try:
                undeclare(entity)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        self._declared = []


def check_node(
    experiment: Experiment, description: dict[str, Any], names: tuple[Any, Any], timing_: Timing
) -> None:
    """The node must serve the same model with the same timing and I/O as this env expects."""
    inputs, outputs = names
    node = description.get("node", "?")
    mismatches = []
    if list(inputs) != description["input_names"]:
        mismatches.append(f"inputs {list(inputs)} vs the node's {description['input_names']}")
    if list(outputs) != description["output_names"]:
        mismatches.append(f"outputs {list(outputs)} vs the node's {description['output_names']}")
    if abs(timing_.sampling_time_s - description["sampling_time_s"]) > 1e-12:
        mismatches.append(f"sampling time {timing_.sampling_time_s} vs {description['sampling_time_s']}")
    if mismatches:
        raise ConfigError(
            f"node {node!r} serves experiment {description.get('experiment')!r} with "
            f"{'; '.join(mismatches)}; start the node with the same experiment file ({experiment.source})"
        )


class RemotePlant(Plant):
    """The model of a node (lockstep over Zenoh): the FMU need not exist on this machine.

    Args:
        experiment: the experiment (the same file the node was started with).
        node: the node's name.
        options: how to open a Zenoh session (ignored when ``session`` is given).
        timeout_s: how long a step or reset may take before :class:`StepTimeout`.
        take_over: take the node over from the client that holds it (its next action is rejected).
    """

    def __init__(
        self,
        experiment: Experiment,
        node: str,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
    ) -> None:
        self.experiment = experiment
        self.node = node
        self.name = f"node {node!r}"
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._time_s = 0.0
        try:
            self.client = NodeClient(
                self._session, node, prefix=prefix, timeout_s=timeout_s, take_over=take_over
            )
            self.info = info_from_summary(self.client.description["model"])
            check_experiment(experiment, self.info)
            self.timing = timing(experiment, self.info)
        except BaseException:
            self.close()
            raise
        self._time_s = self.timing.start_time_s

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        check_node(
            self.experiment, self.client.description, (self.input_names, self.output_names), self.timing
        )

    @property
    def time_s(self) -> float:
        return self._time_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated = 0, False
        frame = self.client.reset(self, dict(values), list(inputs or []))
        self._time_s = frame.sim_time_ns / 1e9
        return frame.values

    def send(self, inputs: Sequence[float] | None) -> None:
        if inputs is None:
            raise ConfigError(f"{self.name}: a lockstep step needs input values")
        self.client.send_action(self, self.episode, self.sample + 1, inputs)

    def receive(self) -> FloatArray:
        frame = self.client.wait(self)
        self._time_s = frame.sim_time_ns / 1e9
        self.sample += 1
        if frame.kind == proto.ERROR and frame.flags & proto.HUNG:
            hint = "the node killed its FMU process; reset() starts a fresh one"
            if "restart the node" in frame.message:
                hint = "the node is unhealthy until restarted"
            raise self.failure(StepTimeout, "the model hung", frame.message, hint, step=self.sample)
        if frame.kind == proto.ERROR:
            detail, _, log = frame.message.partition(FMU_LOG_HEADER)
            raise self.failure(
                StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, step=self.sample, log=log.split("\n  ")
            )
        self.terminated = frame.terminated
        return frame.values

    def answer_ready(self) -> bool:
        return self.client.ready()

    def notify_answers(self, event: threading.Event) -> None:
        self.client.notify = event

    def provenance(self) -> dict[str, str]:
        d = self.client.description
        return {
            "fmu": str(d.get("model", {}).get("path", "")),
            "fmu_sha256": d.get("fmu_sha256", ""),
            "node": self.node,
        }

    def reset_info(self) -> dict[str, Any]:
        return {"node": self.node}

    def close(self) -> None:
        client = getattr(self, "client", None)
        if client is not None:
            client.close()
            self.client = None  # type: ignore[assignment]
        if getattr(self, "_own_session", False) and getattr(self, "_session", None) is not None:
            self._session.close()
            self._session = None


def list_nodes(
    session: Any, *, prefix: str = proto.DEFAULT_PREFIX, pattern: str = "*", timeout_s: float = 2.0
) -> list[str]:
    """Names of the live nodes under ``prefix`` whose name matches the glob ``pattern``."""
    names = []
    for reply in session.liveliness().get(f"{prefix}/**/alive", timeout=timeout_s):
        if reply.ok is None:
            continue
        key = str(reply.ok.key_expr)
        name = key[len(prefix) + 1 : -len("/alive")]
        if fnmatch.fnmatchcase(name, pattern):
            names.append(name)
    return sorted(set(names))


def describe_nodes(
    session: Any, names: list[str], *, prefix: str = proto.DEFAULT_PREFIX, timeout_s: float = 2.0
) -> list[dict[str, Any]]:
    """Each node's info reply (nodes that do not answer in time are reported with an error)."""
    found = []
    for name in names:
        keys = proto.Keys(prefix, name)
        entry: dict[str, Any] = {"node": name, "error": f"no answer within {timeout_s:g} s"}
        for reply in session.get(keys.info, timeout=timeout_s):
            if reply.ok is not None:
                entry = proto.decode_json(reply.ok.payload.to_bytes(), f"info of {name}")
                break
        found.append(entry)
    return found
