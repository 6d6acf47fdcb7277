"""``RemotePlant``: a node as a plant, for a remote env and for a system's component alike (one
constructor: what a use adds, a macro step or a component's own values, are its arguments), and
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
from typing import Any

import numpy as np

from bridge.errors import FMU_LOG_HEADER, ConfigError, StepError, StepTimeout, TransportError
from bridge.experiment.validate import Timing
from bridge.fmu import state_file
from bridge.fmu.vocab import info_from_summary
from bridge.net import protocol as proto
from bridge.net.channel import Waiting
from bridge.net.client import NodeClient
from bridge.net.discovery import describe_nodes, list_nodes, query_info
from bridge.net.served import element_start
from bridge.net.transport import ZenohOptions, open_session
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, MODEL_HUNG, FloatArray, Plant

__all__ = [
    "SERVE_HINT",
    "NodeClient",
    "RemotePlant",
    "answer",
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


class RemotePlant(Plant):
    """The model of a node (lockstep over Zenoh): the FMU need not exist on this machine.

    One plant for a remote env and a system's component alike: the plant's bound inputs and
    outputs are mapped onto the node's by name (a bound name the node does not serve is a
    ConfigError; an input the node serves and nobody binds holds its start value; a remote env
    holds the node to exactly its task's names, ``bridge.env.RemoteFmuEnv``), and the
    master of a system rolls it back for fixed-point iteration (SAVE_STATE or RESTORE_STATE rides
    on the next action, ``bridge.net.node_state``). It checks no task: the env checks its task
    against :attr:`info`, the model the node reports.

    Args:
        node: the node's name.
        options: how to open a Zenoh session (ignored when ``session`` is given).
        timeout_s: how long a step or reset may take before :class:`StepTimeout`.
        take_over: take the node over from the client that holds it (its next action is rejected).
        waiting: how to wait for answers (``bridge.net.channel``; by default an Event).
        sampling_time_s: the sample this plant is used with (a system's macro step); the node
            must step the same (None: as the node says).
        start_time_s: the start time this plant is used with (None: as the node says).
        defaults: values every reset sets under those it is given (a system component's own
            parameters and start values, which the system's task does not know).
        state: a state file's bytes that every episode starts from (:meth:`start_from`).
        label: how errors name the plant (default ``node 'NAME'``); ``where`` ends config errors.
    """

    def __init__(
        self,
        node: str,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        take_over: bool = False,
        waiting: Waiting | None = None,
        sampling_time_s: float | None = None,
        start_time_s: float | None = None,
        defaults: Mapping[str, Any] | None = None,
        state: bytes | None = None,
        label: str | None = None,
        where: str = "",
    ) -> None:
        self.node, self.where = node, where
        self.name = label or f"node {node!r}"
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._time_s = 0.0
        self._state = state  # the state file its episodes start from, sent as the holder
        try:
            self.client = NodeClient(
                self._session, node, prefix=prefix, timeout_s=timeout_s, take_over=take_over, waiting=waiting
            )
            d = self.client.description
            self.info = info_from_summary(d["model"])
            self.timing = self.check_timing(sampling_time_s, start_time_s)
            if state is not None:  # only a holder may send a state: it goes at the first reset
                state_file.decode(state, source="the state to send", max_bytes=len(state))
        except BaseException:
            self.close()
            raise
        self._time_s = self.timing.start_time_s
        self._node_inputs: list[str] = list(d["input_names"])
        self._node_outputs: list[str] = list(d["output_names"])
        self._defaults = dict(defaults or {})
        self._u = np.zeros(len(self._node_inputs))
        self._held: Sequence[float] = []
        self._flags = 0  # SAVE_STATE or RESTORE_STATE for the next action

    def check_timing(self, sampling_time_s: float | None, start_time_s: float | None) -> Timing:
        """The node's timing, checked against the sample and start time this plant is used with
        (None: not checked); a ConfigError says what differs and how to start the node."""
        d = self.client.description
        node_s, node_t0 = float(d["sampling_time_s"]), float(d["start_time_s"])
        same_sample = sampling_time_s is None or math.isclose(node_s, sampling_time_s, rel_tol=1e-12)
        if not same_sample or (start_time_s is not None and node_t0 != start_time_s):
            raise ConfigError(
                f"{self.name}: the node steps {node_s} s from t0 = {node_t0} s; here a sample is "
                f"{sampling_time_s if sampling_time_s is not None else node_s} s from "
                f"{start_time_s if start_time_s is not None else node_t0} s: start the node from the "
                f"same file (`fmu-bridge node EXPERIMENT`; a system's: {SERVE_HINT}){self.where}"
            )
        sample_s = node_s if sampling_time_s is None else sampling_time_s
        return Timing(d["step_size_s"], d["steps_per_sample"], sample_s, node_t0)

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
        description says (its state file, else initialisation)."""
        self._state = None
        if self.client.key is None:
            return {"cleared": True}
        return self.client.clear_state()

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        self._in_index = self._positions(self.input_names, self._node_inputs, "inputs")
        self._out_index = self._positions(self.output_names, self._node_outputs, "outputs")
        # the usual case (both sides bound alike): values pass through without reordering
        self._all_inputs = self._in_index == list(range(len(self._node_inputs)))
        self._all_outputs = self._out_index == list(range(len(self._node_outputs)))

    def _positions(self, names: Sequence[str], served: list[str], what: str) -> list[int]:
        missing = [n for n in names if n not in served]
        if missing:
            raise ConfigError(
                f"{self.name}: the node serves {what} {served}, not {missing}; restart the node with "
                f"this file (`fmu-bridge node EXPERIMENT`; a system's: {SERVE_HINT}){self.where}"
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
        fmu = str(d.get("model", {}).get("path", ""))
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
