"""``RemotePlant``: a node as a plant, for a remote env and for a system's component alike, and
:func:`answer`, the one reading of a node's answer frames. The client's session is
``bridge.net.client.NodeClient`` and discovery ``bridge.net.discovery`` (both re-exported here).

``bridge.env.RemoteFmuEnv`` is the one env over a ``RemotePlant``: the Task (actions,
observations, reward, termination, scenarios and all randomness) runs in the env, only the
model runs in the node, so the same seed gives the same trajectory in-process and remote. The
FMU need not exist on this machine: the node reports its variables, and the Task is checked
against them.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bridge.errors import FMU_LOG_HEADER, ConfigError, StepError, StepTimeout, TransportError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import Timing, check_experiment, resolve_state_file, timing
from bridge.fmu import state_file
from bridge.fmu.vocab import info_from_summary
from bridge.net import protocol as proto
from bridge.net.channel import ChannelWaiting, Waiting
from bridge.net.client import NodeClient
from bridge.net.discovery import describe_nodes, list_nodes, query_info
from bridge.net.served import element_start
from bridge.net.transport import ZenohOptions, open_session
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, MODEL_HUNG, FloatArray, Plant

if TYPE_CHECKING:
    from bridge.plant.system.description import Component

__all__ = [
    "SERVE_HINT",
    "ComponentRole",
    "NodeClient",
    "RemotePlant",
    "answer",
    "check_node",
    "describe_nodes",
    "list_nodes",
    "query_info",
]


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
        raise plant.failure(StepTimeout, MODEL_HUNG, frame.message, hint, step=step, time_s=time_s)
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
        self._state: bytes | None = None  # the state file its episodes start from, sent as the holder
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
            if experiment is not None:  # only a holder may send a state: it goes at the first reset
                self._state = _state_file_bytes(experiment)
        except BaseException:
            self.close()
            raise
        self._time_s = self.timing.start_time_s
        self._node_inputs: list[str] = list(d["input_names"])
        self._node_outputs: list[str] = list(d["output_names"])
        own = {**role.component.parameters, **role.component.start_values} if role is not None else {}
        self._defaults = own
        self._u = np.zeros(len(self._node_inputs))
        self._held: Sequence[float] = []
        self._flags = 0  # SAVE_STATE or RESTORE_STATE for the next action

    def start_from(self, data: bytes) -> dict[str, Any]:
        """Hand the node a state file's bytes: its episodes start from that state from the next
        reset on (``bridge.net.node_start``). Only the holder may send one, and a state ends with
        the lease it was sent in: before the first reset it is checked here and sent with it
        (the answer says ``"pending": true``), and it is sent again whenever a reset reply
        names another state (a new lease: the node restarted, or was taken over and back)."""
        saved = state_file.decode(data, source="the state to send", max_bytes=len(data))
        self._state = data
        if self.client.key is None:
            header = saved.header
            sha = hashlib.sha256(data).hexdigest()
            return {
                "model": header.model_name,
                "time_s": header.time_s,
                "size": header.size,
                "sha256": sha,
                "pending": True,
            }
        return self.client.send_state(data)

    def clear_start(self) -> dict[str, Any]:
        """Drop the state sent to the node: from the next reset on its episodes start as its own
        experiment says (its state file, else initialisation)."""
        self._state = None
        if self.client.key is None:
            return {"cleared": True}
        return self.client.clear_state()

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
            self._u[i] = float(merged.get(name, element_start(self.info, name)))
        if inputs is not None:
            self._u[self._in_index] = inputs
        self._held = held = self._u.tolist()
        frame = self.client.reset(self, merged, held)
        state = self._state
        if state is not None and self.client.start_state != hashlib.sha256(state).hexdigest():
            self.client.send_state(state)  # the holder now: its state, then the reset again
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


def _state_file_bytes(experiment: Experiment) -> bytes | None:
    """``model.reset_policy: {state_file: ...}`` of a remote env's experiment, checked here first
    (sizes, checksum): the node gets the file from here, so the FMU's machine need not have it."""
    path = resolve_state_file(experiment)
    if path is None:
        return None
    saved = state_file.read(path)
    return state_file.encode(saved.header, saved.payload)
