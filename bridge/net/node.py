"""``FmuNode``: one FMU served over Zenoh, in lockstep (training) or real time (deployment).

Physics in the node, task in the env: the node applies the FMU input values it receives,
advances one sample (``n`` FMU steps) and publishes the outputs with their step index and
simulation time. Reset and info are request/reply; a liveliness token shows the node is up.

Every request is checked before use (``bridge.net.requests``): a reset may set only what the
experiment declares, input values must be finite and inside their declared range, payloads
have a size limit; anything else gets an error reply or a REJECT saying what was wrong, and
error texts carry no local paths. One client at a time holds the node (``bridge.net.lease``).

Lockstep: an action stamped with the next step index advances exactly one sample. The same
action again for the last step (same values, same client) gets the last outputs again (a
retry); a different one is rejected as a ``conflict``; stale, early or out-of-order actions are
rejected with a reason and counted, never stepped. Malformed payloads are counted and dropped
while the node keeps serving. An FMU error answers with an ERROR frame carrying the FMU's
message and ends the episode; the node stays up. An action may also save the FMU state before
stepping, or restore the saved one and step again (fixed-point iteration of a system; see
``bridge.net.node_state``).

Health: a reset or step that outlives ``step_timeout_s`` is reported (``health: hung`` in
``info``, an ``unhealthy`` liveliness token, an ERROR frame flagged HUNG). In-process, a hung
native call cannot be interrupted: the node stays unhealthy and exits on SIGTERM without waiting
for it. With ``isolate=True`` the FMU runs in a child process that is killed after the deadline
and restarted by the next reset (one pipe round trip more per step).

Real time: the node advances on a wall clock at ``sampling_time / rate`` (``rate`` 0: as fast
as possible), holds the latest action, publishes every sample and the simulation clock, and
counts overruns.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bridge.errors import BridgeError, PlantError, StepTimeout, TransportError
from bridge.experiment.config import Experiment, as_experiment
from bridge.fmu.vocab import summary_of
from bridge.net import protocol as proto
from bridge.net.lease import Lease
from bridge.net.node_state import SavedState
from bridge.net.requests import BadRequest, RequestRules, check_empty, parse_reset
from bridge.net.ros2.view import RosView, RosViewSettings
from bridge.net.transport import ZenohOptions, open_session, undeclare
from bridge.net.watchdog import Watchdog
from bridge.task.core import Task

if TYPE_CHECKING:
    from bridge.plant.isolated import IsolatedFmuPlant
    from bridge.plant.local import LocalFmuPlant

_log = logging.getLogger(__name__)
Mode = Literal["lockstep", "realtime"]
_PATH = re.compile(r"(?:file://)?(?:/[\w.~+@-]+)+/([\w.~+@-]+)")


def redact(text: str) -> str:
    """``text`` without local paths (``/home/me/plant.fmu`` -> ``.../plant.fmu``): replies leave the host."""
    return _PATH.sub(r".../\1", text)


class Refused(BridgeError):
    """A request the node will not serve now; ``code`` starts the error reply (busy, unhealthy)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


class FmuNode:
    """Serves one FMU instance over Zenoh; ``close()`` (or the context manager) stops it.

    Args:
        isolate: run the FMU in a child process (``IsolatedFmuPlant``): a hung or crashing FMU is
            killed after ``step_timeout_s`` and restarted by the next reset.
        step_timeout_s: the longest a reset or step may take before the node reports it hung.
    """

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
        isolate: bool = False,
        step_timeout_s: float = 10.0,
    ) -> None:
        if mode not in ("lockstep", "realtime"):
            raise BridgeError(f"node mode {mode!r} is unknown; use lockstep or realtime")
        if rate < 0:
            raise BridgeError(f"--rate must be >= 0 (0: as fast as possible), got {rate}")
        if not step_timeout_s > 0:
            raise BridgeError(f"--step-timeout must be > 0 seconds, got {step_timeout_s}")
        self.experiment = exp = as_experiment(experiment)
        self.name, self.mode, self.rate = name, mode, rate
        self.isolated, self.step_timeout_s = isolate, step_timeout_s
        self.keys = proto.Keys(prefix, name)
        self.plant = plant = self._make_plant(exp)
        self.fmu_path, self.info, self.timing = plant.fmu_path, plant.info, plant.timing
        task = Task(exp, self.info.variables, self.timing)  # for the input/output names only
        self.input_names, self.output_names = task.input_names, task.output_names
        plant.bind(self.input_names, self.output_names)
        self.rules = RequestRules(exp, self.info.variables, self.input_names)
        self._actions = proto.PlainFrames(proto.ACTION, len(self.input_names))
        self.lease = Lease(name)
        self.saved = SavedState(plant, mode)
        self.counters: Counter[str] = Counter()
        self.health, self.health_detail = "ok", ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.episode, self.step, self._ended = 0, -1, True
        self._last_frame = b""
        self._last_action: tuple[int, bytes] = (0, b"")
        self._latest_inputs: list[float] | None = None
        self._held_inputs = [_start_value(self.info.variables[n].start) for n in self.input_names]
        self._checksum = plant.provenance()["fmu_sha256"]
        self._own_session = session is None
        self._session = session if session is not None else open_session(options)
        self._declared: list[Any] = []
        self._unhealthy_token: Any = None
        self._thread: threading.Thread | None = None
        self._ros_settings = ros
        self._ros: RosView | None = None
        self.watchdog = Watchdog(step_timeout_s, self._on_hung, name=name)
        self.closed_cleanly = True
        self._declare()

    def _make_plant(self, exp: Experiment) -> LocalFmuPlant | IsolatedFmuPlant:
        isolation = exp.model.isolation  # the experiment's model.isolation, or --isolate
        if self.isolated or isolation is not None:
            from bridge.plant.isolated import IsolatedFmuPlant

            return IsolatedFmuPlant(
                exp,
                timeout_s=isolation.timeout if isolation is not None else self.step_timeout_s,
                memory_limit_mb=isolation.memory_limit_mb if isolation is not None else None,
                restart=True,
            )
        from bridge.plant.local import LocalFmuPlant

        return LocalFmuPlant(exp)

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
            s.liveliness().declare_subscriber(k.client(0), self._on_client_token),
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
                follower=self._clock_follower(self._ros_settings),
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

    def close(self, timeout_s: float = 1.0) -> bool:
        """Stop serving within about ``2 * timeout_s``, even with the FMU hung in a native call.

        Returns whether everything was released; False means a call into the FMU never returned
        (the process should then exit without waiting for it: ``os._exit``)."""
        if self._stop.is_set():
            return self.closed_cleanly
        self._stop.set()
        self.watchdog.stop()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
        locked = self._lock.acquire(timeout=timeout_s)
        if not locked and self.isolated:
            self.plant.close()  # kills the child: the blocked step returns with PlantDied
            locked = self._lock.acquire(timeout=timeout_s)
        teardown = threading.Thread(target=self._teardown, name=f"close-{self.name}", daemon=True)
        teardown.start()
        teardown.join(timeout=timeout_s)
        if locked:
            try:
                self.saved.clear()
                self.plant.close()
            finally:
                self._lock.release()
        self.closed_cleanly = locked and not teardown.is_alive()
        return self.closed_cleanly

    def _teardown(self) -> None:
        if self._ros is not None:
            self._ros.close()
        for entity in reversed([*self._declared, self._unhealthy_token]):
            if entity is None:
                continue
            try:
                undeclare(entity, attempts=20)
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        if self._own_session:
            self._session.close()

    # -- actions (run on Zenoh's threads) ------------------------------------------------------------
    def _on_action(self, sample: Any) -> None:
        payload = sample.payload.to_bytes()
        try:
            fields = self._actions.read(payload)
            if fields is None or not self._plain_step(fields, payload):
                self._any_action(payload)
        except Exception:  # never let a handler die: count it, log it, keep serving
            self.counters["internal_errors"] += 1
            _log.exception("node %s: an action could not be handled", self.name)

    def _any_action(self, payload: bytes) -> None:
        try:
            frame = proto.decode(payload, expected_values=len(self.input_names))
            if frame.kind != proto.ACTION:
                raise TransportError(f"a {proto.KIND_NAMES[frame.kind]} frame on the actions key")
            if frame.sim_time_ns < 0:
                raise TransportError(f"client id {frame.sim_time_ns} is negative")
            if frame.flags & ~proto.ACTION_FLAGS:
                raise TransportError(f"action flags {frame.flags:#x} are unknown")
        except TransportError as exc:
            self._malformed(str(exc))
            return
        self._accept(frame, payload)

    def _plain_step(self, fields: tuple[Any, ...], payload: bytes) -> bool:
        """The next step of this episode from its holder, no flags, inputs in range: step at once.

        Exactly the case in which ``_accept`` would end in ``_advance``, checked with fewer calls
        (the step's own cost on a busy machine); False leaves every other case to ``_accept``."""
        flags, episode, step, client = fields[2:6]
        if flags or client < 0 or self.mode != "lockstep":
            return False
        if episode != self.episode or step != self.step + 1 or self._ended:
            return False
        values = list(fields[7:])
        if self.health == "hung" or not self.lease.allows(client) or self.rules.inputs(values) is not None:
            return False
        if not self._lock.acquire(blocking=False):
            return False
        try:
            if episode != self.episode or step != self.step + 1 or self._ended:  # changed meanwhile
                return False
            self._last_action = (client, payload[proto.HEADER.size :])
            self._advance(values)
        finally:
            self._lock.release()
        return True

    def _accept(self, frame: proto.Frame, payload: bytes) -> None:
        client = frame.sim_time_ns
        if not self.lease.allows(client):
            return self._reject(frame, "not_holder", self.lease.refusal(client))
        values = list(frame.floats)
        reason = self.rules.inputs(values)
        if reason is not None:
            return self._reject(frame, "out_of_range", reason)
        if self.health == "hung":
            return self._reject(frame, "unhealthy", self.health_detail)
        if frame.flags and (reason := self.saved.check(frame.flags)) is not None:
            return self._reject(frame, "state", reason)
        if not self._lock.acquire(timeout=self.step_timeout_s):
            return self._reject(frame, "busy", "the node is busy with a step or reset that has not returned")
        try:
            if self.mode == "realtime":
                self._latest_inputs = values
                self.counters["held"] += 1
            else:
                self._lockstep(frame, values, (client, payload[proto.HEADER.size :]))
        finally:
            self._lock.release()
        return None

    def _lockstep(self, frame: proto.Frame, values: list[float], action: tuple[int, bytes]) -> None:
        if frame.episode != self.episode:
            return self._reject(
                frame, "stale", f"action for episode {frame.episode}; the node is in {self.episode}"
            )
        if frame.flags & proto.RESTORE_STATE:
            if not self._state(frame, self.saved.restore):
                return None
            self.step, self._ended, self._last_frame = frame.step - 1, False, b""
            self.counters["restored"] += 1
        elif frame.step == self.step and self._last_frame:
            if action != self._last_action:
                return self._reject(
                    frame, "conflict", f"step {frame.step} was already taken with another action or client"
                )
            self.counters["duplicate"] += 1  # a retry: the same answer again, never a second step
            self._pub.put(self._last_frame)
            return None
        if frame.step != self.step + 1:
            return self._reject(
                frame, "out_of_order", f"action for step {frame.step}; next is {self.step + 1}"
            )
        if self._ended:
            return self._reject(frame, "ended", "the episode is over: reset first")
        if frame.flags & proto.SAVE_STATE and not self._state(frame, self.saved.save):
            return None
        self._last_action = action
        self._advance(values)
        return None

    def _state(self, frame: proto.Frame, change: Callable[[int, int], str | None]) -> bool:
        """Save or restore the state before ``frame``'s step; False: refused or failed (answered)."""
        try:
            reason = change(frame.episode, frame.step)
        except PlantError as exc:
            self._fail(exc)
            return False
        if reason is not None:
            self._reject(frame, "state", reason)
        return reason is None

    def _advance(self, inputs: list[float] | None) -> None:
        plant = self.plant
        self.watchdog.begin("step %d of episode %d", self.step + 1, self.episode)
        try:
            outputs = plant.step(inputs)
        except PlantError as exc:
            self._fail(exc)
            return
        finally:
            self.watchdog.end()
        if inputs is not None:
            self._held_inputs = inputs
        self.step += 1
        self.counters["steps"] += 1
        flags = proto.TERMINATED if plant.terminated else 0
        self._ended = plant.terminated
        time_ns = round(plant.time_s * 1e9)
        values = outputs.tolist()
        self._last_frame = proto.encode_values(
            proto.OUTPUTS, self.episode, self.step, time_ns, values, flags=flags
        )
        self._pub.put(self._last_frame)
        if self._ros is not None:
            self._ros.publish(time_ns, values)

    def _fail(self, exc: PlantError) -> None:
        hung = isinstance(exc, StepTimeout)
        self.counters["hung" if hung else "fmu_errors"] += 1
        self.step += 1
        self._ended = True
        self.health = "failed"
        self.health_detail = redact(f"episode {self.episode} ended at step {self.step}: {exc.detail}")
        _log.warning("node %s: episode %d ended by a plant error: %s", self.name, self.episode, exc)
        # The cause in the plant's words (and the FMU's log); the client puts it in its own error.
        log = getattr(exc, "log", [])
        detail = exc.detail + ("\nFMU log (most recent last):\n  " + "\n  ".join(log[-20:]) if log else "")
        flags = proto.FAILED | (proto.HUNG if hung else 0)
        time_ns = round(self.plant.time_s * 1e9)
        self._last_frame = proto.encode_message(
            proto.ERROR, self.episode, self.step, time_ns, redact(detail), flags=flags
        )
        self._pub.put(self._last_frame)

    def _on_hung(self, what: str, elapsed_s: float) -> None:
        """The watchdog saw a reset or step outlive the deadline (the FMU is stuck in native code)."""
        if self.isolated:  # the child is killed at the deadline by the plant itself
            return
        self.counters["hung"] += 1
        self.health = "hung"
        self.health_detail = (
            f"the FMU has not returned from {what} for {elapsed_s:.1f} s "
            f"(deadline {self.step_timeout_s:g} s); "
            "it cannot be interrupted in this process: restart the node, and run unstable FMUs with --isolate"
        )
        _log.error("node %s: %s", self.name, self.health_detail)
        self._unhealthy_token = self._session.liveliness().declare_token(self.keys.unhealthy)
        frame = proto.encode_message(
            proto.ERROR, self.episode, self.step + 1, 0, self.health_detail, flags=proto.FAILED | proto.HUNG
        )
        self._pub.put(frame)

    def _reject(self, frame: proto.Frame, reason: str, detail: str) -> None:
        self.counters[f"rejected_{reason}"] += 1
        if _log.isEnabledFor(logging.INFO):
            _log.info("node %s rejected an action (%s): %s", self.name, reason, detail)
        # stamped with the refused client's id: no other client takes it for its own answer
        reject = proto.encode_message(
            proto.REJECT, frame.episode, frame.step, frame.sim_time_ns, f"{reason}: {detail}"
        )
        self._pub.put(reject)

    def _malformed(self, reason: str) -> None:
        self.counters["malformed"] += 1
        if self.counters["malformed"] <= 5 or self.counters["malformed"] % 1000 == 0:
            _log.warning(
                "node %s dropped a malformed payload (%d so far): %s",
                self.name,
                self.counters["malformed"],
                reason,
            )

    # -- reset and info ------------------------------------------------------------------------------
    def _on_reset(self, query: Any) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            reply = self._checked_reset(payload)
        except BadRequest as exc:
            return self._reply_err(query, "bad_request", str(exc))
        except Refused as exc:
            return self._reply_err(query, exc.code, str(exc))
        except BridgeError as exc:
            return self._reply_err(query, "failed", f"reset failed: {exc}")
        except Exception as exc:  # never let a handler die: count it, log it, answer
            _log.exception("node %s: a reset could not be handled", self.name)
            what = f"the node could not handle the reset ({type(exc).__name__})"
            return self._reply_err(query, "internal", what)
        query.reply(self.keys.reset, reply)
        return None

    def _checked_reset(self, payload: bytes) -> bytes:
        request = parse_reset(payload)
        values = self.rules.values(request.values)
        if request.inputs is not None:
            if len(request.inputs) != len(self.input_names):
                raise BadRequest(
                    f"reset request: {len(request.inputs)} inputs, expected {len(self.input_names)} "
                    f"({list(self.input_names)})"
                )
            reason = self.rules.inputs(request.inputs)
            if reason is not None:
                raise BadRequest(f"reset request: {reason}")
        refusal = self.lease.acquire(request.client, request.zid, request.take_over)
        if refusal is not None:
            raise Refused("busy", refusal)
        return self.reset(values, request.inputs, request.episode)

    def _reply_err(self, query: Any, code: str, message: str) -> None:
        self.counters[f"reset_{code}"] += 1
        query.reply_err(f"{code}: {redact(message)}".encode())

    def reset(self, values: dict[str, Any], inputs: list[float] | None, episode: int) -> bytes:
        """Reset the model for ``episode``; returns the OUTPUTS frame of step 0."""
        if self.health == "hung":
            raise Refused("unhealthy", f"node {self.name!r} is unhealthy: {self.health_detail}")
        if not self._lock.acquire(timeout=self.step_timeout_s):
            raise Refused("busy", f"node {self.name!r} is busy with a step that has not returned")
        try:
            self.saved.clear()  # a state of the last episode (and of this FMU instance) is no use
            self.watchdog.begin("the reset of episode %d", episode)
            try:
                outputs = self.plant.reset(values, inputs)
            finally:
                self.watchdog.end()
            if inputs is not None:
                self._latest_inputs = self._held_inputs = list(inputs)
            self.episode, self.step, self._ended = episode, 0, False
            self.health, self.health_detail = "ok", ""
            self.counters["resets"] += 1
            time_ns = round(self.plant.time_s * 1e9)
            self._last_frame = proto.encode_values(proto.OUTPUTS, episode, 0, time_ns, outputs)
            self._last_action = (0, b"")
            # step 0 goes on the outputs key too: recorders and deployed agents see every sample
            self._pub.put(self._last_frame)
            if self._ros is not None:
                self._ros.publish(time_ns, outputs.tolist())
            self._next_tick = time.monotonic()
            return self._last_frame
        finally:
            self._lock.release()

    def _on_client_token(self, sample: Any) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.DELETE and self.lease.release_token(str(sample.key_expr)):
            _log.info("node %s: the lease ended, its holder's session is gone", self.name)

    def _on_info(self, query: Any) -> None:
        try:
            check_empty(query.payload.to_bytes() if query.payload is not None else None, "an info request")
            query.reply(self.keys.info, proto.encode_json(self.describe()))
        except BadRequest as exc:
            self.counters["info_bad_request"] += 1
            query.reply_err(f"bad_request: {exc}".encode())
        except Exception as exc:
            _log.exception("node %s: an info request could not be handled", self.name)
            query.reply_err(f"internal: the node could not describe itself ({type(exc).__name__})".encode())

    # -- the ROS view ---------------------------------------------------------------------------------
    def _ros_actions(self, values: dict[str, float]) -> None:
        """Input values by name from the ROS view: held in real time, one sample each in lockstep."""
        if self.lease.holder is not None:
            self.counters["ros_rejected_not_holder"] += 1
            return
        current = self._latest_inputs or self._held_inputs
        merged = [float(values.get(name, current[i])) for i, name in enumerate(self.input_names)]
        if self.rules.inputs(merged) is not None:
            self.counters["ros_rejected_out_of_range"] += 1
            return
        if self.health == "hung" or not self._lock.acquire(timeout=self.step_timeout_s):
            self.counters["ros_rejected_unhealthy"] += 1
            return
        try:
            if self.mode == "realtime" or self._ros_follows_clock:
                self._latest_inputs = merged  # held: time (the wall's, or /clock) steps the FMU
            elif not self._ended:
                self._advance(merged)
            else:  # lockstep after the episode ended: no step, but not silently
                self.counters["ros_ignored_episode_ended"] += 1
        finally:
            self._lock.release()

    @property
    def _ros_follows_clock(self) -> bool:
        return self._ros_settings is not None and self._ros_settings.follow_clock

    def _clock_follower(self, settings: RosViewSettings) -> Any:
        """With ``ros.follow_clock``: steps on another simulator's /clock (bridge.net.ros2.clock)."""
        if not settings.follow_clock:
            return None
        from bridge.net.ros2.clock import ClockFollower

        def start() -> int:
            model = self.experiment.model
            self.reset({**model.parameters, **model.start_values}, None, self.episode + 1)
            return round(self.plant.time_s * 1e9)

        def step() -> int | None:
            with self._lock:
                if self._ended:
                    return None
                self._advance(self._latest_inputs or self._held_inputs)
                return round(self.plant.time_s * 1e9)

        return ClockFollower(round(self.timing.sampling_time_s * 1e9), start, step)

    def _ros_reset(self) -> tuple[bool, str]:
        model = self.experiment.model
        refusal = self.lease.acquire(0, "", False)
        if refusal is not None:
            return False, f"reset refused: {refusal}"
        try:
            self.reset({**model.parameters, **model.start_values}, None, self.episode + 1)
        except BridgeError as exc:
            return False, redact(f"reset failed: {exc}")
        return True, f"reset to t0 (episode {self.episode})"

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
            "input_range": [list(pair) for pair in zip(self.rules.low, self.rules.high)],
            "episode": self.episode,
            "step": self.step,
            "time_s": self.plant.time_s,
            "health": self.health,
            "health_detail": self.health_detail,
            "holder": self.lease.describe(),
            "isolated": self.isolated,
            "can_save_state": self.saved.available,
            "save_state_refusal": self.saved.refusal or "",
            "step_timeout_s": self.step_timeout_s,
            "counters": dict(self.counters),
            "model": _summary_without_paths(summary_of(self.info)),
        }

    # -- real time -----------------------------------------------------------------------------------
    def _run_realtime(self) -> None:
        period = self.timing.sampling_time_s / self.rate if self.rate > 0 else 0.0
        self._next_tick = time.monotonic()
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception:  # the stepping thread must outlive anything: count, log, go on
                self.counters["internal_errors"] += 1
                _log.exception("node %s: a real-time step could not be handled", self.name)
                self._stop.wait(0.1)
            self._pace(period)

    def _tick(self) -> None:
        if not self._lock.acquire(timeout=0.5):
            return
        try:
            if not self._ended:
                self._advance(self._latest_inputs)  # zero-order hold of the latest action
                if not self._ended:
                    self._clock_pub.put(np.int64(round(self.plant.time_s * 1e9)).tobytes())
        finally:
            self._lock.release()

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


def _start_value(start: Any) -> float:
    return float(start) if isinstance(start, int | float) else 0.0


def _summary_without_paths(summary: dict[str, Any]) -> dict[str, Any]:
    """The model summary for the network: the FMU's file name, not where it lives on this machine."""
    if "path" in summary:
        summary = {**summary, "path": Path(str(summary["path"])).name}
    return summary
