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
import math
import secrets
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

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
from bridge.net.channel import ChannelWaiting, EventWaiting, Waiting
from bridge.net.lease import NO_TOKEN, reset_proof
from bridge.net.transport import ZenohOptions, open_session, undeclare
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant

if TYPE_CHECKING:
    from bridge.plant.system.description import Component

_log = logging.getLogger(__name__)


class NodeInfo(BaseModel):
    """What a client needs from a node's ``info`` reply; anything else in it is kept as is."""

    model_config = ConfigDict(extra="allow")

    node: str
    zid: str = Field(default="", max_length=64)  # "": a publisher of recorded frames
    experiment: str = ""
    fmu_sha256: str = ""
    input_names: list[str] = Field(max_length=proto.MAX_SIGNALS)
    output_names: list[str] = Field(max_length=proto.MAX_SIGNALS)
    step_size_s: float = Field(gt=0)
    steps_per_sample: int = Field(ge=1)
    sampling_time_s: float = Field(gt=0)
    start_time_s: float
    can_save_state: bool = False
    save_state_refusal: str = ""
    model: dict[str, Any]


class _HolderEntry(BaseModel):
    model_config = ConfigDict(extra="allow")
    client: str
    zid: str = ""


class _ModelEntry(BaseModel):
    model_config = ConfigDict(extra="allow")
    model_name: str = "?"


class NodeListing(BaseModel):
    """A node's ``info`` as ``fmu-bridge nodes`` lists it: every field typed, the missing ones
    filled (a recording published with ``replay --publish`` answers with fewer)."""

    model_config = ConfigDict(extra="allow")

    node: str
    zid: str = Field(default="", max_length=64)
    mode: str = "?"
    experiment: str = ""
    version: str = ""
    health: str = "?"
    holder: _HolderEntry | None = None
    episode: int = 0
    step: int = -1
    time_s: float = 0.0
    pid: int = 0
    counters: dict[str, int] = {}
    model: _ModelEntry = _ModelEntry()
    input_names: list[str] = []
    output_names: list[str] = []


def listed_info(payload: bytes, node: str, replier: str | None) -> dict[str, Any]:
    """A node's ``info`` reply for a listing (:class:`NodeListing`); TransportError if malformed."""
    data = proto.decode_json(payload, f"the info reply of node {node!r}", limit=proto.MAX_INFO_BYTES)
    try:
        listing = NodeListing.model_validate(data)
    except ValidationError as exc:
        raise _malformed_info(node, exc) from None
    if listing.node != node or (replier is not None and listing.zid not in ("", replier)):
        raise TransportError(
            f"the info reply for node {node!r} names node {listing.node!r}: not the node asked for"
        )
    return listing.model_dump()


def _malformed_info(node: str, exc: Exception) -> TransportError:
    first = exc.errors()[0] if isinstance(exc, ValidationError) else {"msg": repr(exc)[:200], "loc": ()}
    where = ".".join(str(p) for p in first.get("loc", ()))
    return TransportError(
        f"node {node!r} sent an info reply that the protocol does not allow"
        f"{f' ({where})' if where else ''}: {first['msg']}; is it a node of another version?"
    )


def checked_info(payload: bytes, node: str, replier: str | None) -> dict[str, Any]:
    """A node's ``info`` reply, checked against :class:`NodeInfo` (and its model summary), from
    the session it names; a TransportError naming the node says what is wrong otherwise."""
    data = proto.decode_json(payload, f"the info reply of node {node!r}", limit=proto.MAX_INFO_BYTES)
    try:
        info = NodeInfo.model_validate(data)
        info_from_summary(info.model)
    except (ValidationError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise _malformed_info(node, exc) from None
    if info.node != node or (replier is not None and info.zid not in ("", replier)):
        raise TransportError(
            f"the info reply for node {node!r} names node {info.node!r} of session {info.zid}, "
            f"and came from session {replier}: not the node asked for"
        )
    return data


def _all() -> Any:
    """Ask every queryable of a key, not the best one: an impostor cannot hide the node."""
    import zenoh

    return zenoh.QueryTarget.ALL


def _replier(reply: Any) -> str | None:
    rid = getattr(reply, "replier_id", None)
    return str(rid.zid) if rid is not None else None


def query_info(session: Any, keys: proto.Keys, timeout_s: float) -> dict[str, Any]:
    """The node's ``info`` reply; TransportError if no node of that name answers in
    ``timeout_s``, if two sessions answer as that node, or if the reply is malformed."""
    # A query sent before routes exist finds no queryable and returns at once: retry until the
    # timeout, so a just-opened session or a node that is still starting is found.
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        answers = [
            (reply.ok.payload.to_bytes(), _replier(reply))
            for reply in session.get(keys.info, target=_all(), timeout=max(0.05, min(remaining, 1.0)))
            if reply.ok is not None
        ]
        sessions = {zid for _, zid in answers}
        if len(sessions) > 1:
            raise TransportError(
                f"{len(sessions)} Zenoh sessions answer as node {keys.node!r} "
                f"({sorted(map(str, sessions))}); "
                "a node's name must be its own: stop the impostor, or use another name"
            )
        if answers:
            return checked_info(answers[0][0], keys.node, answers[0][1])
        if remaining <= 0:
            break
        time.sleep(min(0.1, max(remaining, 0.0)))
    raise TransportError(
        f"no FMU node named {keys.node!r} answers on {keys.info} within {timeout_s:g} s; "
        f"start one with `fmu-bridge node EXPERIMENT --name {keys.node}` and check the Zenoh endpoints "
        "(`fmu-bridge nodes` lists the live ones)"
    )


class NodeClient:
    """Talks to one node: stamped actions out, the matching frame back.

    The client has a random id, sent with every reset and action, and a liveliness token
    ``<prefix>/<node>/clients/<id>`` that ends the node's lease when this session goes away.
    ``waiting`` says how it waits for an answer (``bridge.net.channel``; by default an Event).
    """

    def __init__(
        self,
        session: Any,
        node: str,
        *,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
        waiting: Waiting | None = None,
    ) -> None:
        self.keys = proto.Keys(prefix, node)
        self.name = node
        self.session = session
        self.timeout_s = timeout_s
        self.take_over = take_over
        self.client_id = secrets.randbits(63) | 1
        self.notify: threading.Event | None = None  # set too whenever an answer arrives (vector envs)
        self.waiting: Waiting = waiting if waiting is not None else EventWaiting()
        self.want: tuple[int, int] = (-1, -1)
        self.deadline = 0.0
        self.frame: proto.Frame | None = None
        self.alive = True
        self.key: bytes | None = None  # the session key of the lease, from the reset reply
        # the token first: it reaches the node before any reset (a lease needs it), and its
        # declaration has gone through long before the info query's round trip is over
        token = session.liveliness().declare_token(self.keys.client(self.client_id))
        try:
            self.description = query_info(session, self.keys, timeout_s)
        except BaseException:
            undeclare(token)
            raise
        self.node_zid = str(self.description.get("zid") or "")  # answers come from this session only
        self.outputs = len(self.description["output_names"])
        self._declared = [
            token,
            self.waiting.start(self),
            session.liveliness().declare_subscriber(self.keys.alive, self._on_liveliness, history=True),
        ]
        self._pub = session.declare_publisher(self.keys.actions)
        self._declared.append(self._pub)

    def take(self, frame: proto.Frame, payload: bytes) -> bool:
        """Keep ``frame`` if it answers the last action: its step, from the leased node's session
        (its MAC is right under the session key), and not another client's reject; whether it did."""
        if (frame.episode, frame.step) != self.want:
            return False
        if frame.kind == proto.REJECT and frame.sim_time_ns not in (0, self.client_id):
            return False
        key = self.key
        if key is not None and not proto.verify(payload, key):
            return False  # not from the node this client leased: another peer's frame
        self.frame = frame
        return True

    def _on_liveliness(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE:
            self.alive = False
            self.waiting.wake()  # wake a waiting step at once
        else:
            self.alive = True

    def send_action(
        self, plant: Plant, episode: int, step: int, inputs: Sequence[float], flags: int = 0
    ) -> None:
        """Publish the action for ``step``; ``flags``: SAVE_STATE or RESTORE_STATE (rollback)."""
        if not self.alive:
            raise self._dead(plant)
        self.frame = None
        self.waiting.arm()
        self.want = (episode, step)
        self.deadline = time.monotonic() + self.timeout_s
        action = proto.encode_values(
            proto.ACTION, episode, step, self.client_id, inputs, flags=flags, key=self.key
        )
        self._pub.put(action)
        self.waiting.sent()

    def ready(self) -> bool:
        """Whether ``wait`` would return (or raise) at once: an answer, a death or the deadline."""
        return self.waiting.ready()

    def wait(self, plant: Plant) -> proto.Frame:
        """The frame that answers the last action; raises if the node died or timed out."""
        if not self.waiting.wait():
            raise plant.failure(
                StepTimeout,
                f"no answer within {self.timeout_s:g} s",
                f"no outputs for step {self.want[1]} within {self.timeout_s:g} s",
                "the node may be overloaded, hung or unreachable; "
                f"timeout_s sets the limit [{self.keys.base}]",
            )
        frame = self.frame
        if frame is None:
            raise self._dead(plant)
        return frame

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
        request: dict[str, Any] = {
            "episode": episode,
            "values": values,
            "inputs": inputs,
            "client": self.client_id,
            "zid": str(self.session.zid()),
            "take_over": self.take_over,
        }
        if self.key is not None:  # the holder shows it holds the session key
            request["proof"] = reset_proof(self.key, self.client_id, episode)
        self.want = (episode, 0)
        payload = proto.encode_json(request)
        start = time.monotonic()
        while True:
            sent = time.monotonic()
            refusal = ""
            replies = self.session.get(
                self.keys.reset, payload=payload, target=_all(), timeout=self.timeout_s
            )
            for reply in replies:
                if self.node_zid and _replier(reply) not in (None, self.node_zid):
                    continue  # another session answering for the node: not believed
                if reply.ok is not None:
                    return self._session(plant, reply.ok, episode)
                refusal = reply.err.payload.to_bytes().decode(errors="replace")
                break
            if NO_TOKEN in refusal and time.monotonic() - start < 0.5 * self.timeout_s:
                time.sleep(0.05)  # the node has not seen this client's token yet: ask again
                continue
            if refusal:
                raise self._reset_refused(plant, refusal)
            break
        if not self.alive or time.monotonic() - sent < 0.5 * self.timeout_s:
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

    def _session(self, plant: Plant, sample: Any, episode: int) -> proto.Frame:
        """The step-0 frame of a reset reply, and the session key beside it, both checked."""
        payload = sample.payload.to_bytes()
        key = sample.attachment.to_bytes() if sample.attachment is not None else b""
        try:
            if len(key) != proto.KEY_SIZE:
                raise TransportError(f"a session key of {len(key)} bytes, expected {proto.KEY_SIZE}")
            if not proto.verify(payload, key):
                raise TransportError("its step-0 frame is not signed with the session key")
            frame = proto.decode(payload, expected_values=self.outputs)
            if (frame.kind, frame.episode, frame.step) != (proto.OUTPUTS, episode, 0):
                raise TransportError(
                    f"a {proto.KIND_NAMES[frame.kind]} frame for step {frame.step} of episode "
                    f"{frame.episode}, expected the outputs of step 0 of episode {episode}"
                )
        except TransportError as exc:
            raise TransportError(f"{plant.name}: the reset reply is malformed: {exc}") from None
        self.key = key
        return frame

    def _reset_refused(self, plant: Plant, message: str) -> BridgeError:
        code, _, detail = message.partition(": ")
        if code == "unhealthy":
            return plant.failure(PlantDied, "the plant is unhealthy", detail, "restart the node", step=None)
        return TransportError(f"{plant.name}: the reset was refused ({code}): {detail}")

    def close(self) -> None:
        self.waiting.close()
        for entity in reversed(self._declared):
            try:
                undeclare(entity)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        self._declared = []


def answer(plant: Plant, frame: proto.Frame, episode: int, step: int, outputs: int) -> proto.Frame:
    """The one reading of a node's answer to ``step`` of ``episode``: an OUTPUTS frame is
    returned; an ERROR frame is the model's failure (:class:`StepError`, or :class:`StepTimeout`
    when flagged HUNG), at the frame's simulation time; a REJECT is the node refusing the action
    (:class:`TransportError`). Every remote plant reads frames through this function, so a node
    gives the same error through a remote env and through a system."""
    if frame.kind == proto.OUTPUTS:
        if len(frame.floats) != outputs:
            raise TransportError(
                f"{plant.name} answered step {step} of episode {episode} with {len(frame.floats)} "
                f"values; it serves {outputs} outputs"
            )
        return frame
    if frame.kind == proto.REJECT:
        raise TransportError(f"{plant.name} rejected step {step} of episode {episode}: {frame.message}")
    time_s = frame.sim_time_ns / 1e9
    if frame.flags & proto.HUNG:
        hint = "the node killed its FMU process; reset() starts a fresh one"
        if "restart the node" in frame.message:
            hint = "the node is unhealthy until restarted"
        raise plant.failure(StepTimeout, "the model hung", frame.message, hint, step=step, time_s=time_s)
    detail, _, log = frame.message.partition(FMU_LOG_HEADER)
    raise plant.failure(
        StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, step=step, time_s=time_s, log=log.split("\n  ")
    )


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


@dataclass(frozen=True)
class ComponentRole:
    """A remote plant that is one component of a system: its sample is the macro step."""

    component: Component
    macro_step_s: float
    start_time_s: float
    where: str = ""


class RemotePlant(Plant):
    """The model of a node (lockstep over Zenoh): the FMU need not exist on this machine.

    The same plant serves a remote env (the node serves the env's experiment: the names must
    match exactly) and a system's component (:meth:`for_component`: the plant's bound inputs and
    outputs are mapped onto the node's by name, and the master rolls it back for fixed-point
    iteration: SAVE_STATE or RESTORE_STATE rides on the next action, ``bridge.net.node_state``).

    Args:
        experiment: the experiment (the same file the node was started with).
        node: the node's name.
        options: how to open a Zenoh session (ignored when ``session`` is given).
        timeout_s: how long a step or reset may take before :class:`StepTimeout`.
        take_over: take the node over from the client that holds it (its next action is rejected).
        waiting: how to wait for answers (``bridge.net.channel``; by default an Event).
    """

    def __init__(
        self,
        experiment: Experiment | None,
        node: str,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
        waiting: Waiting | None = None,
        role: ComponentRole | None = None,
    ) -> None:
        self.experiment, self.node, self.role = experiment, node, role
        self.name = f"node {node!r}" if role is None else f"component {role.component.name!r} (node {node!r})"
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._time_s = 0.0
        try:
            self.client = NodeClient(
                self._session, node, prefix=prefix, timeout_s=timeout_s, take_over=take_over, waiting=waiting
            )
            d = self.client.description
            self.info = info_from_summary(d["model"])
            if role is not None:
                self.timing = _check_timing(self.name, d, role.macro_step_s, role.start_time_s, role.where)
            else:
                assert experiment is not None, "a remote env's plant needs its experiment"
                check_experiment(experiment, self.info)
                self.timing = timing(experiment, self.info)
        except BaseException:
            self.close()
            raise
        self._time_s = self.timing.start_time_s
        self._node_inputs: list[str] = list(d["input_names"])
        self._node_outputs: list[str] = list(d["output_names"])
        self._defaults = dict(role.component.parameters) if role is not None else {}
        self._u = np.zeros(len(self._node_inputs))
        self._held: Sequence[float] = []
        self._flags = 0  # SAVE_STATE or RESTORE_STATE for the next action

    @property
    def component(self) -> Component | None:
        """The system's component this plant is (None: a remote env's plant)."""
        return self.role.component if self.role is not None else None

    @classmethod
    def for_component(
        cls,
        component: Component,
        macro_step_s: float,
        start_time_s: float,
        *,
        session: Any,
        prefix: str,
        timeout_s: float,
        where: str = "",
    ) -> RemotePlant:
        """A system's component served by its node; answers wait in a ring channel (the master
        waits for every node of a macro step in turn)."""
        return cls(
            None,
            component.node or component.name,
            session=session,
            prefix=prefix,
            timeout_s=timeout_s,
            waiting=ChannelWaiting(),
            role=ComponentRole(component, macro_step_s, start_time_s, where),
        )

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        if self.role is None:
            assert self.experiment is not None
            names = (self.input_names, self.output_names)
            check_node(self.experiment, self.client.description, names, self.timing)
        self._in_index = self._positions(self.input_names, self._node_inputs, "inputs")
        self._out_index = self._positions(self.output_names, self._node_outputs, "outputs")
        # the usual case (both sides bound alike): values pass through without reordering
        self._all_inputs = self._in_index == list(range(len(self._node_inputs)))
        self._all_outputs = self._out_index == list(range(len(self._node_outputs)))

    def _positions(self, names: Sequence[str], served: list[str], what: str) -> list[int]:
        missing = [n for n in names if n not in served]
        if missing:
            where = self.role.where if self.role is not None else ""
            raise ConfigError(
                f"{self.name}: the node serves {what} {served}, not {missing}; restart the node with "
                f"this experiment file ({SERVE_HINT}){where}"
            )
        return [served.index(n) for n in names]

    @property
    def time_s(self) -> float:
        return self._time_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated, self._flags = 0, False, 0
        merged = {**self._defaults, **values}
        for i, name in enumerate(self._node_inputs):  # inputs nobody binds: their start values
            self._u[i] = float(merged.get(name, _start(self.info.variables[name].start)))
        if inputs is not None:
            self._u[self._in_index] = inputs
        self._held = held = self._u.tolist()
        frame = self.client.reset(self, merged, held)
        self._time_s = frame.sim_time_ns / 1e9
        return frame.values if self._all_outputs else frame.values[self._out_index]

    def send(self, inputs: Sequence[float] | None) -> None:
        flags, self._flags = self._flags, 0
        if inputs is None:
            inputs = self._held
        elif not self._all_inputs:
            self._u[self._in_index] = inputs
            inputs = self._u.tolist()
        self._held = inputs
        self.client.send_action(self, self.episode, self.sample + 1, inputs, flags)

    def receive(self) -> FloatArray:
        frame = self.client.wait(self)
        step = self.sample + 1
        if frame.kind != proto.REJECT:  # a refused action took no step
            self._time_s, self.sample = frame.sim_time_ns / 1e9, step
        frame = answer(self, frame, self.episode, step, self.client.outputs)
        self.terminated = frame.terminated
        return frame.values if self._all_outputs else frame.values[self._out_index]

    # -- saved states (rollback): carried by the next action -----------------------------------------
    @property
    def can_save(self) -> bool:
        """Whether the node can save and restore its FMU state (its ``info`` says so)."""
        return bool(self.client.description.get("can_save_state", False))

    @property
    def save_refusal(self) -> str:
        """Why the node cannot save its state ("" if it can)."""
        if self.can_save:
            return ""
        return str(self.client.description.get("save_state_refusal") or "the node is too old to save states")

    def save(self) -> tuple[int, bool, float, list[float]]:
        """The node saves its state with the next action (SAVE_STATE); this keeps the step stamp."""
        self._flags = proto.SAVE_STATE
        return self.sample, self.terminated, self._time_s, list(self._held)

    def restore(self, saved: tuple[int, bool, float, list[float]]) -> None:
        """The next action goes back to the saved state first (RESTORE_STATE), stamped as then."""
        self.sample, self.terminated, self._time_s, held = saved
        self._held = list(held)
        self._u[:] = held
        self._flags = proto.RESTORE_STATE

    def discard(self, saved: tuple[int, bool, float, list[float]]) -> None:
        """Nothing to free here: the node keeps one state, replaced by the next save."""
        self._flags = 0

    def answer_ready(self) -> bool:
        return self.client.ready()

    def notify_answers(self, event: threading.Event) -> None:
        self.client.notify = event

    def provenance(self) -> dict[str, str]:
        d = self.client.description
        fmu = (
            str(self.role.component.fmu) if self.role is not None else str(d.get("model", {}).get("path", ""))
        )
        return {"fmu": fmu, "fmu_sha256": d.get("fmu_sha256", ""), "node": self.node}

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


SERVE_HINT = "`fmu-bridge system serve SYSTEM.yaml` starts the component nodes"


def _check_timing(name: str, d: Mapping[str, Any], macro_s: float, t0: float, where: str) -> Timing:
    if not math.isclose(d["sampling_time_s"], macro_s, rel_tol=1e-12) or d["start_time_s"] != t0:
        raise ConfigError(
            f"{name}: the node steps {d['sampling_time_s']} s from t0 = {d['start_time_s']} s; the system "
            f"has macro step {macro_s} s from {t0} s: start the node from this system file ({SERVE_HINT})"
            f"{where}"
        )
    return Timing(d["step_size_s"], d["steps_per_sample"], macro_s, t0)


def _start(value: Any) -> float:
    try:
        return float(value) if value is not None else 0.0
    except (TypeError, ValueError):
        return 0.0


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
                try:
                    entry = listed_info(reply.ok.payload.to_bytes(), name, _replier(reply))
                except TransportError as exc:
                    entry = {"node": name, "error": str(exc)}
                break
        found.append(entry)
    return found
