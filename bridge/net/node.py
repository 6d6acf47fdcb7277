"""``FmuNode``: one FMU served over Zenoh, in lockstep (training) or real time (deployment).

Physics in the node, task in the env: the node applies the FMU input values it receives,
advances one sample (``n`` FMU steps) and publishes the outputs with their step index and
simulation time. Reset and info are request/reply; a liveliness token shows the node is up.

Lockstep: an action stamped with the next step index advances exactly one sample. A duplicate
of the last step gets the last outputs again (a client retry); stale, early or out-of-order
actions are rejected with a reason and counted, never stepped. Malformed payloads are counted
and dropped while the node keeps serving. An FMU error answers with an ERROR frame carrying
the FMU's message and ends the episode; the node stays up.

Real time: the node advances on a wall clock at ``sampling_time / rate`` (``rate`` 0: as fast
as possible), holds the latest action, publishes every sample and the simulation clock, and
counts overruns.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bridge.errors import BridgeError, StepError, TransportError
from bridge.experiment.config import Experiment, as_experiment
from bridge.fmu.vocab import summary_of
from bridge.net import protocol as proto
from bridge.net.ros2.view import RosView, RosViewSettings
from bridge.net.transport import ZenohOptions, open_session, undeclare
from bridge.plant.local import LocalFmuPlant
from bridge.task.core import Task

_log = logging.getLogger(__name__)
Mode = Literal["lockstep", "realtime"]


class FmuNode:
    """Serves one FMU instance over Zenoh; ``close()`` (or the context manager) stops it."""

    def __init__(
        self,
        experiment: Experiment | str | Path,
        *,
        name: str,
        mode: Mode = "lockstep",
        rate: float = 1.0,
        options: ZenohOptions | None = None,
        prefix: str = proto.DEFAULT_PREFIX,
        session: Any = None,
        ros: RosViewSettings | None = None,
    ) -> None:
        if mode not in ("lockstep", "realtime"):
            raise BridgeError(f"node mode {mode!r} is unknown; use lockstep or realtime")
        if rate < 0:
            raise BridgeError(f"--rate must be >= 0 (0: as fast as possible), got {rate}")
        self.experiment = exp = as_experiment(experiment)
        self.name, self.mode, self.rate = name, mode, rate
        self.keys = proto.Keys(prefix, name)
        self.plant = plant = LocalFmuPlant(exp)
        self.fmu_path, self.info, self.timing = plant.fmu_path, plant.info, plant.timing
        task = Task(exp, self.info.variables, self.timing)  # for the input/output names only
        self.input_names, self.output_names = task.input_names, task.output_names
        plant.bind(self.input_names, self.output_names)
        self.counters: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.episode, self.step, self._ended = 0, -1, True
        self._last_frame = b""
        self._latest_inputs: list[float] | None = None
        self._checksum = plant.provenance()["fmu_sha256"]
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._declared: list[Any] = []
        self._thread: threading.Thread | None = None
        self._ros_settings = ros
        self._ros: RosView | None = None
        self._declare()

    # -- life cycle --------------------------------------------------------------------------------
    def _declare(self) -> None:
        s, k = self._session, self.keys
        self._pub = s.declare_publisher(k.outputs)
        self._clock_pub = s.declare_publisher(k.clock)
        self._declared += [
            self._pub,
            self._clock_pub,
            s.declare_subscriber(k.actions, self._on_action),
            s.declare_queryable(k.reset, self._on_reset, complete=True),
            s.declare_queryable(k.info, self._on_info, complete=True),
            s.liveliness().declare_token(k.alive),
        ]
        if self._ros_settings is not None:
            self._ros = RosView(
                s,
                self._ros_settings,
                name=self.name,
                output_names=self.output_names,
                input_names=self.input_names,
                on_actions=self._ros_actions,
                on_reset=self._ros_reset,
                realtime=self.mode == "realtime",
            )
        if self.mode == "realtime":
            # A real-time node runs from the start with the experiment's nominal values.
            model = self.experiment.model
            self.reset({**model.parameters, **model.start_values}, None, 0)
            self._thread = threading.Thread(target=self._run_realtime, name=f"node-{self.name}", daemon=True)
            self._thread.start()
        _log.info("node %s serving %s (%s) on %s/*", self.name, self.info.model_name, self.mode, k.base)

    def __enter__(self) -> FmuNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def serve_forever(self) -> None:
        """Block until ``close()`` is called from another thread (or a signal handler)."""
        while not self._stop.wait(0.5):
            pass

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._ros is not None:
            self._ros.close()
        for entity in reversed(self._declared):
            try:
                undeclare(entity)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        if self._own_session:
            self._session.close()
        with self._lock:
            self.plant.close()

    # -- handlers (run on Zenoh's threads) -----------------------------------------------------------
    def _on_action(self, sample: Any) -> None:
        try:
            frame = proto.decode(sample.payload.to_bytes(), expected_values=len(self.input_names))
            if frame.kind != proto.ACTION:
                raise TransportError(f"a {proto.KIND_NAMES[frame.kind]} frame on the actions key")
        except TransportError as exc:
            self._malformed(str(exc))
            return
        with self._lock:
            if self.mode == "realtime":
                self._latest_inputs = frame.values.tolist()
                return
            self._lockstep(frame)

    def _lockstep(self, frame: proto.Frame) -> None:
        if frame.episode != self.episode:
            return self._reject(
                frame, "stale", f"action for episode {frame.episode}; the node is in {self.episode}"
            )
        if frame.step == self.step and self._last_frame:
            self.counters["duplicate"] += 1  # a retry: the same answer again, never a second step
            self._pub.put(self._last_frame)
            return None
        if frame.step != self.step + 1:
            return self._reject(
                frame, "out_of_order", f"action for step {frame.step}; next is {self.step + 1}"
            )
        if self._ended:
            return self._reject(frame, "ended", "the episode is over: reset first")
        self._advance(frame.values.tolist())
        return None

    def _advance(self, inputs: list[float] | None) -> None:
        plant = self.plant
        try:
            outputs = plant.step(inputs)
        except StepError as exc:
            self._fail(exc)
            return
        self.step += 1
        self.counters["steps"] += 1
        flags = proto.TERMINATED if plant.terminated else 0
        self._ended = plant.terminated
        time_ns = round(plant.time_s * 1e9)
        self._last_frame = proto.encode_values(
            proto.OUTPUTS, self.episode, self.step, time_ns, outputs, flags=flags
        )
        self._pub.put(self._last_frame)
        if self._ros is not None:
            self._ros.publish(time_ns, outputs.tolist())

    def _fail(self, exc: StepError) -> None:
        self.counters["fmu_errors"] += 1
        self.step += 1
        self._ended = True
        _log.warning("node %s: episode %d ended by an FMU error: %s", self.name, self.episode, exc)
        # The cause in the FMU's words (and its log); the client puts it in its own StepError.
        detail = exc.detail + (
            "\nFMU log (most recent last):\n  " + "\n  ".join(exc.log[-20:]) if exc.log else ""
        )
        self._last_frame = proto.encode_message(
            proto.ERROR, self.episode, self.step, round(self.plant.time_s * 1e9), detail, flags=proto.FAILED
        )
        self._pub.put(self._last_frame)

    def _reject(self, frame: proto.Frame, reason: str, detail: str) -> None:
        self.counters[f"rejected_{reason}"] += 1
        _log.info("node %s rejected an action (%s): %s", self.name, reason, detail)
        self._pub.put(proto.encode_message(proto.REJECT, frame.episode, frame.step, 0, f"{reason}: {detail}"))

    def _malformed(self, reason: str) -> None:
        self.counters["malformed"] += 1
        if self.counters["malformed"] <= 5 or self.counters["malformed"] % 1000 == 0:
            _log.warning(
                "node %s dropped a malformed payload (%d so far): %s",
                self.name,
                self.counters["malformed"],
                reason,
            )

    def _on_reset(self, query: Any) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b"{}"
            request = proto.decode_json(payload, "reset request")
            reply = self.reset(
                request.get("values", {}), request.get("inputs"), int(request.get("episode", 0))
            )
        except (BridgeError, ValueError, TypeError) as exc:
            self.counters["reset_errors"] += 1
            query.reply_err(f"reset failed: {exc}".encode())
            return
        query.reply(self.keys.reset, reply)

    def reset(self, values: dict[str, Any], inputs: list[float] | None, episode: int) -> bytes:
        """Reset the model for ``episode``; returns the OUTPUTS frame of step 0."""
        with self._lock:
            outputs = self.plant.reset(values, inputs)
            if inputs is not None:
                self._latest_inputs = list(inputs)
            self.episode, self.step, self._ended = episode, 0, False
            self.counters["resets"] += 1
            time_ns = round(self.plant.time_s * 1e9)
            self._last_frame = proto.encode_values(proto.OUTPUTS, episode, 0, time_ns, outputs)
            # step 0 goes on the outputs key too: recorders and deployed agents see every sample
            self._pub.put(self._last_frame)
            if self._ros is not None:
                self._ros.publish(time_ns, outputs.tolist())
            self._next_tick = time.monotonic()
            return self._last_frame

    def _ros_actions(self, values: dict[str, float]) -> None:
        """Input values by name from the ROS view: held in real time, one sample each in lockstep."""
        with self._lock:
            current = self._latest_inputs or [float(v) for v in self._inputs_now()]
            merged = [values.get(name, current[i]) for i, name in enumerate(self.input_names)]
            if self.mode == "realtime":
                self._latest_inputs = merged
            elif not self._ended:
                self._advance(merged)

    def _inputs_now(self) -> list[float]:
        return self.plant.current_inputs()

    def _ros_reset(self) -> tuple[bool, str]:
        model = self.experiment.model
        try:
            self.reset({**model.parameters, **model.start_values}, None, self.episode + 1)
        except BridgeError as exc:
            return False, f"reset failed: {exc}"
        return True, f"reset to t0 (episode {self.episode})"

    def _on_info(self, query: Any) -> None:
        query.reply(self.keys.info, proto.encode_json(self.describe()))

    def describe(self) -> dict[str, Any]:
        """What ``fmu-bridge nodes`` and remote envs learn about this node."""
        return {
            "node": self.name,
            "mode": self.mode,
            "rate": self.rate,
            "pid": os.getpid(),
            "experiment": self.experiment.name,
            "version": self.experiment.version,
            "fmu_sha256": self._checksum,
            "step_size_s": self.timing.step_size_s,
            "steps_per_sample": self.timing.steps_per_sample,
            "sampling_time_s": self.timing.sampling_time_s,
            "start_time_s": self.timing.start_time_s,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "episode": self.episode,
            "step": self.step,
            "time_s": self.plant.time_s,
            "counters": dict(self.counters),
            "model": summary_of(self.info),
        }

    # -- real time -----------------------------------------------------------------------------------
    def _run_realtime(self) -> None:
        period = self.timing.sampling_time_s / self.rate if self.rate > 0 else 0.0
        self._next_tick = time.monotonic()
        while not self._stop.is_set():
            with self._lock:
                if not self._ended:
                    self._advance(self._latest_inputs)  # zero-order hold of the latest action
                    if not self._ended:
                        self._clock_pub.put(np.int64(round(self.plant.time_s * 1e9)).tobytes())
            self._pace(period)

    def _pace(self, period: float) -> None:
        if period <= 0:
            if self._ended:
                self._stop.wait(0.01)
            return
        self._next_tick += period
        delay = self._next_tick - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)
        elif -delay > period:
            self.counters["overruns"] += 1
            if self.counters["overruns"] <= 5 or self.counters["overruns"] % 100 == 0:
                _log.warning(
                    "node %s: real-time overrun by %.1f ms (%d so far)",
                    self.name,
                    -delay * 1e3,
                    self.counters["overruns"],
                )
            self._next_tick = time.monotonic()
