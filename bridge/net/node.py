"""``FmuNode``: one plant served over Zenoh, in lockstep (training) or real time (deployment).

The node applies the input values it receives, advances one sample and publishes the outputs
with their step index and simulation time; reset and info are queries
(``bridge.net.node_replies``); its Zenoh entities live in ``bridge.net.node_link``. Who owns what:

- the plant (``bridge.plant.factory.fmu_plant`` of the node's
  :class:`~bridge.plant.spec.PlantSpec`, the factory envs use) steps the FMU, in this process or
  in a child process (``plant.isolated``);
- :class:`~bridge.net.served.Served` says what the node serves: signal names, what a reset may
  set, input ranges, timing; ``bridge.net.requests`` checks every request against it;
- both come from the caller: ``bridge.serving`` builds them from an experiment or a system file
  (the node never reads a task);
- :class:`~bridge.net.lockstep.Lockstep` decides what an action does (step, retry, or a REJECT
  with its reason) and :class:`~bridge.net.lease.Lease` who may send one;
- :class:`~bridge.net.node_actions.ActionPath` carries out what the rules order for an action
  that is not the plain next step (restore, retry, save, reject);
- :class:`~bridge.net.realtime.RealtimeDriver` owns the thread that steps on a wall clock, and
  :class:`~bridge.net.node_realtime.RealtimeStepping` what it does at each deadline;
- this module wires them to Zenoh: it decodes, sends, counts and logs.

An FMU error answers with an ERROR frame carrying the FMU's message and ends the episode; the
node stays up. A reset or step that outlives ``step_timeout_s`` is reported (``health: hung``,
an ``unhealthy`` liveliness token, an ERROR frame flagged HUNG); an in-process FMU hung in a
native call cannot be interrupted, so the node stays unhealthy and exits on SIGTERM without
waiting for it, while an isolated one is killed by its plant and restarted by the next reset.
"""

from __future__ import annotations

import contextlib
import logging
import math
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any, Literal

from bridge.errors import PlantError, StepTimeout
from bridge.net import lockstep as ls
from bridge.net import node_replies as replies
from bridge.net import node_start
from bridge.net import protocol as proto
from bridge.net.lease import Lease
from bridge.net.node_actions import ActionPath
from bridge.net.node_health import Health
from bridge.net.node_link import NodeLink
from bridge.net.node_realtime import RealtimeStepping, Sample
from bridge.net.node_setup import check_arguments, served_plant
from bridge.net.node_state import SavedState
from bridge.net.realtime import Pacing, RealtimeDriver
from bridge.net.requests import Refused, RequestRules, redact
from bridge.net.ros2.view import RosViewSettings
from bridge.net.served import Served, element_start
from bridge.net.transport import ZenohOptions, open_session
from bridge.net.watchdog import Watchdog
from bridge.plant.spec import PlantSpec

_log = logging.getLogger(__name__)
Mode = Literal["lockstep", "realtime"]
_BODY = proto.HEADER.size
__all__ = ["FmuNode", "Refused", "redact"]


class FmuNode:
    """Serves one plant over Zenoh; ``close()`` (or the context manager) stops it.

    ``bridge.serving.experiment_node`` builds one from an experiment file.

    Args:
        spec: the plant the node serves (the model, its time grid, whether it runs isolated).
        served: what the node serves: names, what a reset may set, input ranges, timing.
        isolate: run the FMU in a child process as ``model.isolation`` would: a hung or crashing
            FMU is killed after ``step_timeout_s`` and restarted by the next reset.
        step_timeout_s: the longest a reset or step may take before the node reports it hung.
        pacing: how a real-time node keeps its period (``bridge.net.realtime.Pacing``).
        ros_node: a ROS node to serve the ROS view on (the managed node's lifecycle node).
        managed: start inactive: no stepping until :meth:`activate` (a lifecycle node drives it).
    """

    def __init__(
        self,
        spec: PlantSpec,
        served: Served,
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
        pacing: Pacing | None = None,
        ros_node: Any = None,
        managed: bool = False,
    ) -> None:
        check_arguments(name, mode, rate, step_timeout_s)
        self.name, self.mode, self.rate = name, mode, rate
        self.keys = proto.Keys(prefix, name)
        self.spec = spec
        plant, self.step_timeout_s = served_plant(
            spec, served, isolate=isolate, step_timeout_s=step_timeout_s
        )
        self.plant, self.served, self.info, self.timing = plant, served, plant.info, served.timing
        self.input_names, self.output_names = served.input_names, served.output_names
        self.rules = RequestRules(self.served, self.info.variables)
        self.lease = Lease(name)
        self.lockstep = ls.Lockstep(self.lease, self.rules.inputs)
        self._inputs = len(self.input_names)
        self.saved = SavedState(plant, mode)
        self.sent = node_start.SentState()  # a state the holder sent (ends with its lease)
        self.counters: Counter[str] = Counter()
        self.health = Health(name, self.step_timeout_s, self.counters)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._time_ns = round(self.timing.start_time_s * 1e9)
        self._latest_inputs: list[float] | None = None
        self.start_inputs = tuple(element_start(self.info, n) for n in self.input_names)  # u[2]: an element
        self._held_inputs = list(self.start_inputs)
        self.ros_parameters: dict[str, Any] = {}  # FMU parameters set over ROS, for the next ~/reset
        # ROS lockstep (anonymous actions) ends an episode after model.episode_duration
        episode_s = served.episode_duration_s
        self.episode_samples = (
            round(episode_s / self.timing.sampling_time_s) if math.isfinite(episode_s) else sys.maxsize
        )
        self.checksum = plant.provenance()["fmu_sha256"]
        self._own_session = session is None
        self._driver: RealtimeDriver | None = None
        self._realtime: RealtimeStepping | None = None
        self.follows_clock = ros is not None and ros.follow_clock  # steps on another simulator's /clock
        if managed:  # a managed node steps once activated, for every client alike
            self.lockstep.inactive = inactive_reason(name)
        self._pacing = pacing
        # in-process only: an isolated plant is bounded by its own deadline and never hangs the node
        self.watchdog = Watchdog(self.step_timeout_s, self._on_hung, name=name, watch=not plant.isolated)
        self.slowest_reset_s = 0.0  # measured: the deadline of later resets follows it
        self.closed_cleanly = True
        session = session if session is not None else open_session(options)
        try:
            self._declare(session, ros, ros_node)
        except BaseException:
            self.watchdog.stop()
            plant.close()
            if self._own_session:
                session.close()
            raise

    @property
    def _follower(self) -> Any:
        """The clock follower of ``--follow-clock`` (None without one)."""
        return self._link.ros.follower if self._link.ros is not None else None

    health_detail = property(lambda self: self.health.detail, doc="Why the node is not ``ok``.")
    zid = property(lambda self: self._link.zid, doc="The node's Zenoh session id (answers come from it).")

    @property
    def acting(self) -> bool:
        """Whether the node steps now (False: a managed node that is not active)."""
        return not self.lockstep.inactive

    def check_active(self) -> None:
        """Refused (code ``inactive``) while a managed node is not active: no reset, no step,
        from a native client, a ROS action or reset, or a clock alike."""
        if self.lockstep.inactive:
            raise Refused(ls.INACTIVE, self.lockstep.inactive)

    @property
    def isolated(self) -> bool:
        """Whether the FMU runs in a child process (``--isolate`` or ``model.isolation``)."""
        return self.plant.isolated

    # -- life cycle --------------------------------------------------------------------------------
    def _declare(self, session: Any, ros: RosViewSettings | None, ros_node: Any) -> None:
        self._link = link = NodeLink(
            session,
            self.keys,
            own_session=self._own_session,
            node=self,
            on_reset=lambda query: replies.answer_reset(self, query),
            on_info=lambda query: replies.answer_info(self, query),
            on_state=lambda query: node_start.answer_state(self, query),
            lease=self.lease,
        )
        self._pub = link.outputs
        self._actions = ActionPath(
            self.lockstep, self.saved, self.counters, advance=self._advance, fail=self._fail,
            put=link.outputs.put, name=self.name,
        )  # fmt: skip
        if ros is not None:
            link.add_ros(self, ros, ros_node)
        if self.acting:
            self._start_realtime()
        elif self._follower is not None:
            self._follower.pause()
        _log.info(
            "node %s serving %s (%s) on %s/*", self.name, self.info.model_name, self.mode, link.keys.base
        )

    def _start_realtime(self) -> None:
        """A real-time node runs from now with the nominal values (a lockstep node: nothing)."""
        if self.mode != "realtime":
            return
        if not self.counters["resets"]:  # the first start; a managed node resumes where it stopped
            self.reset({}, None, 0)
        self._realtime = rt = RealtimeStepping(
            lambda: self._advance(self._latest_inputs, (0, b""), hold=True), self._publish,
            clock=self._link.clock, ended=lambda: self.lockstep.ended, lock=self._lock,
            period_s=self.timing.sampling_time_s / self.rate if self.rate > 0 else 0.0,
            name=self.name, counters=self.counters, pacing=self._pacing,
        )  # fmt: skip
        self._driver = rt.driver
        self._driver.start()

    def activate(self) -> None:
        """A managed node starts stepping: actions (native and ROS) are taken, a real-time node
        runs, a clock follower lines up with its clock again at the next tick."""
        self.lockstep.inactive = ""
        self._start_realtime()
        if self._follower is not None:
            self._follower.resume()

    def deactivate(self) -> None:
        """A managed node stops stepping (the FMU keeps its state; :meth:`activate` resumes):
        actions and resets are refused with the reason ``inactive``, from native clients too."""
        self.lockstep.inactive = inactive_reason(self.name)
        if self._follower is not None:
            self._follower.pause()
        if self._driver is not None:
            self._driver.stop(self.step_timeout_s)
            self._driver = self._realtime = None

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
        if self._driver is not None:
            self._driver.stop(timeout_s)
        if self._follower is not None:  # its thread steps under the lock taken next
            self._follower.close(timeout_s)
        locked = self._lock.acquire(timeout=timeout_s)
        if not locked and self.isolated:
            self.plant.close()  # kills the child: the blocked step returns with PlantDied
            locked = self._lock.acquire(timeout=timeout_s)
        released = self._link.close_within(timeout_s)
        if locked:
            try:
                self.saved.clear()
                self.plant.close()
            finally:
                self._lock.release()
        self.closed_cleanly = locked and released
        return self.closed_cleanly

    # -- actions (decoded by NodeLink on Zenoh's threads) -----------------------------------------------
    def plain_step(self, fields: tuple[Any, ...], payload: bytes) -> bool:
        """The fast path: the next step from the holder, in range (``Lockstep.plain``); False
        leaves the action to :meth:`accept`."""
        episode, step, client = fields[3:6]
        values = list(fields[7 : 7 + self._inputs])
        if self._driver is not None or not self.lockstep.plain(episode, step, client, values, payload):
            return False
        if not self._lock.acquire(blocking=False):
            return False
        try:
            if not self.lockstep.is_next(episode, step):  # changed meanwhile
                return False
            self._advance(values, (client, payload[_BODY:]))
        finally:
            self._lock.release()
        return True

    def accept(self, frame: proto.Frame, payload: bytes) -> None:
        """Any well-formed action: admitted, ordered and served, or rejected with its reason."""
        values, action = list(frame.floats), (frame.sim_time_ns, payload[_BODY:])
        refused = self.lockstep.admit(action[0], values, frame.flags, self.saved.refusal, payload)
        if refused is not None:
            return self._actions.reject(frame, refused, payload)
        if not self._lock.acquire(timeout=self.step_timeout_s):
            return self._actions.reject(frame, ls.Reject(ls.BUSY, "the node is busy with a step or reset"))
        try:
            if self._driver is not None:
                self._latest_inputs = values
                self.counters["held"] += 1
            else:
                self._actions.serve(frame, values, action)
        finally:
            self._lock.release()
        return None

    def _advance(
        self, inputs: list[float] | None, action: tuple[int, bytes], *, hold: bool = False
    ) -> Sample | None:
        """One step; its frame is published now, or with ``hold`` returned for the real-time
        stepping to publish at the next deadline (None: the step failed and was answered)."""
        plant, state = self.plant, self.lockstep
        self.watchdog.begin("step %d of episode %d", state.step + 1, state.episode)
        try:
            outputs = plant.step(inputs)
        except PlantError as exc:
            self._fail(exc, action)
            return None
        finally:
            self.watchdog.end()
        if inputs is not None:
            self._held_inputs = inputs
        self.counters["steps"] += 1
        self._time_ns = time_ns = round(plant.time_s * 1e9)
        values = outputs.tolist()
        frame = state.stepped(action, values, time_ns, plant.terminated)
        if hold:
            return frame, time_ns, values, state.ended
        self._publish(frame, time_ns, values)
        return None

    def _publish(self, frame: bytes, time_ns: int, values: list[float]) -> None:
        self._pub.put(frame)
        if self._link.ros is not None:
            self._link.ros.publish(time_ns, values)

    def _fail(self, exc: PlantError, action: tuple[int, bytes]) -> None:
        state = self.lockstep
        detail = self.health.failed(exc, state.episode, state.step + 1)
        self._pub.put(state.failed(action, detail, self._time_ns, isinstance(exc, StepTimeout)))

    def _on_hung(self, what: str, elapsed_s: float, deadline_s: float) -> None:
        """The watchdog saw a reset or step outlive the deadline (the FMU is stuck in native code);
        in-process plants only (an isolated plant kills its child at its own deadline)."""
        self.lockstep.unhealthy = detail = self.health.hung(what, elapsed_s, deadline_s)
        self._link.unhealthy()
        self._pub.put(self.lockstep.error(detail, self._time_ns, hung=True))  # t: where it hung

    @contextlib.contextmanager
    def locked(self, what: str) -> Iterator[None]:
        """Hold the node's FMU for ``what`` (no step or reset meanwhile); Refused if a step hangs."""
        if not self._lock.acquire(timeout=self.step_timeout_s):
            raise Refused("busy", f"node {self.name!r} is busy with a step that has not returned ({what})")
        try:
            yield
        finally:
            self._lock.release()

    def reset_deadline_s(self) -> float:
        """How long the in-process FMU's next reset may take before the node reports it hung: the
        first one (the model's initialisation, unmeasured) as long as it runs, as an isolated
        plant's; later ones ``--step-timeout`` or 4 x the slowest reset so far, the longer."""
        if not self.counters["resets"]:
            return math.inf
        return max(self.step_timeout_s, 4.0 * self.slowest_reset_s)

    def reset(self, values: dict[str, Any], inputs: list[float] | None, episode: int) -> bytes:
        """Reset the model for ``episode``; returns the OUTPUTS frame of step 0.

        ``values`` are set over the node's nominal ones (its experiment's parameters and start
        values): a request that names none runs the served experiment, not the FMU's defaults,
        on every path (a client's reset, a ROS reset, a real-time start)."""
        self.check_active()
        values = {**self.served.nominal, **values}
        if self.health.is_hung:
            raise Refused("unhealthy", f"node {self.name!r} is unhealthy: {self.health.detail}")
        if not self._lock.acquire(timeout=self.step_timeout_s):
            raise Refused("busy", f"node {self.name!r} is busy with a step that has not returned")
        try:
            self.saved.clear()  # a state of the last episode (and of this FMU instance) is no use
            if self._realtime is not None:
                self._realtime.drop()  # a sample of the last episode is not published
            self.watchdog.begin("the reset of episode %d", episode, deadline_s=self.reset_deadline_s())
            started = time.monotonic()
            try:
                outputs = self.plant.reset(values, inputs)
            finally:
                self.watchdog.end()
            self.slowest_reset_s = max(self.slowest_reset_s, time.monotonic() - started)
            if inputs is not None:
                self._latest_inputs = self._held_inputs = list(inputs)
            self.health.ok()
            self.counters["resets"] += 1
            self._time_ns = time_ns = round(self.plant.time_s * 1e9)
            frame = proto.encode_values(proto.OUTPUTS, episode, 0, time_ns, outputs, key=self.lease.key)
            self.lockstep.started(episode, frame)
            # step 0 goes on the outputs key too: recorders and deployed agents see every sample
            self._publish(frame, time_ns, outputs.tolist())
            if self._driver is not None:
                self._driver.restart_clock()
            return frame
        finally:
            self._lock.release()

    # -- the ROS view and real time ---------------------------------------------------------------------
    def current_inputs(self) -> list[float]:
        """The input values held now (the latest action, else the last stepped or start ones)."""
        return self._latest_inputs or self._held_inputs

    def apply(self, inputs: list[float]) -> bool:
        """Anonymous inputs (the ROS view): held in real time or when following a clock (time
        steps the FMU), one step in lockstep; False when the node is unhealthy or busy."""
        if self.health.is_hung or not self._lock.acquire(timeout=self.step_timeout_s):
            return False
        try:
            if self.mode == "realtime" or self.follows_clock:
                self._latest_inputs = inputs
            elif not self.episode_over():
                self._advance(inputs, (0, b""))
            else:  # lockstep after the episode ended (or ran its duration): no step, not silently
                self.counters["ros_ignored_episode_ended"] += 1
                if self.counters["ros_ignored_episode_ended"] == 1:
                    _log.warning(
                        "node %s: ROS action after the end of episode %d (step %d of %d, "
                        "model.episode_duration %g s): not stepped; call ~/reset for the next episode",
                        self.name, self.lockstep.episode, self.lockstep.step, self.episode_samples,
                        self.served.episode_duration_s,
                    )  # fmt: skip
        finally:
            self._lock.release()
        return True

    def episode_over(self) -> bool:
        """Whether the episode has ended: terminated or failed, or (lockstep, where actions come
        over ROS) ``model.episode_duration`` run; real time and an external clock go on."""
        state = self.lockstep
        lockstep = self.mode != "realtime" and not self.follows_clock
        return state.ended or (lockstep and state.step >= self.episode_samples)

    def clock_step(self) -> int | None:
        """One sample on an external clock's tick (``--follow-clock``) with the latest inputs held:
        the FMU time reached in ns, or None when the episode is over."""
        with self._lock:
            if self.lockstep.ended or self.lockstep.inactive or self._stop.is_set():
                return None
            self._advance(self.current_inputs(), (0, b""))
            return round(self.plant.time_s * 1e9)

    def clock_start(self) -> int:
        """A new episode with the nominal values for an external clock: its start time in ns."""
        self.reset({}, None, self.lockstep.episode + 1)
        return round(self.plant.time_s * 1e9)

    def describe(self) -> dict[str, Any]:
        """What ``fmu-bridge nodes`` and remote envs learn about this node."""
        return replies.describe(self)


def inactive_reason(name: str) -> str:
    """Why a managed node that is not active serves no step and no reset (``Lockstep.inactive``)."""
    return (
        f"the managed node is not active: node {name!r} is a ROS 2 lifecycle node that steps and resets "
        "for no client until it is activated; activate it first (the lifecycle transition activate, "
        "e.g. ros2 lifecycle set <node> activate)"
    )
