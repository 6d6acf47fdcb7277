"""The lockstep rules of a node, with no network in sight: who may step, which step is next.

A node keeps one episode at a time: a reset starts it at step 0, each accepted action advances
it by exactly one step. An action is judged in two stages, both here:

1. :meth:`Lockstep.admit`, before the node's lock is taken: the sender must hold the lease
   (``not_holder``), its values must be finite and in range (``out_of_range``), the node must be
   healthy (``unhealthy``), active (``inactive``: a managed node that is not in its lifecycle
   state active steps for nobody) and able to serve the action's state flags (``state``).
2. :meth:`Lockstep.order`, under the lock: an action for another episode is ``stale``; the same
   action again for the last step is a retry (the last answer again, never a second step), a
   different one for that step a ``conflict``; any other step but the next is ``out_of_order``;
   nothing steps an episode that is over (``ended``). A RESTORE_STATE action first goes back to
   the saved state, so the step it names becomes the next one again.

:meth:`Lockstep.plain` is the hot path: the one case that ends in a step (the next step of this
episode from the holder, no flags, values in range), checked with the fewest operations. It
agrees with ``admit`` + ``order`` on every action it accepts; everything else goes the long way.

The node (``bridge.net.node``) sends and logs; this module only decides, and is tested as plain
unit tests (``tests/net/test_lockstep.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from bridge.net import protocol as proto
from bridge.net.lease import Lease

STALE, OUT_OF_ORDER, CONFLICT, NOT_HOLDER = "stale", "out_of_order", "conflict", "not_holder"
OUT_OF_RANGE, ENDED, STATE, UNHEALTHY, BUSY = "out_of_range", "ended", "state", "unhealthy", "busy"
INACTIVE = "inactive"
REASONS = (STALE, OUT_OF_ORDER, CONFLICT, NOT_HOLDER, OUT_OF_RANGE, ENDED, STATE, UNHEALTHY, BUSY, INACTIVE)


@dataclass(frozen=True, slots=True)
class Reject:
    """An action refused: ``reason`` (one of ``REASONS``) and what was wrong."""

    reason: str
    detail: str

    def frame(self, episode: int, step: int, client: int, key: bytes | None) -> bytes:
        """The REJECT frame, stamped with the refused client's id (no other client takes it for
        its own answer), signed with ``key`` (see ``Lockstep.reject_key``)."""
        message = f"{self.reason}: {self.detail}"
        return proto.encode_message(proto.REJECT, episode, step, client, message, key=key)


@dataclass(frozen=True, slots=True)
class Step:
    """An action to serve: ``retry`` answers the last frame again; else step once, after saving
    (``save``) or restoring (``restore``) the state when the action's flags ask for it."""

    retry: bool = False
    save: bool = False
    restore: bool = False


RETRY = Step(retry=True)
ADVANCE = Step()


class Lockstep:
    """The episode and step of one node, and the rules for the next action.

    Args:
        lease: who holds the node.
        check_inputs: the reason input values are refused (None: in range).
    """

    def __init__(self, lease: Lease, check_inputs: Callable[[Sequence[float]], str | None]) -> None:
        self.lease = lease
        self.check_inputs = check_inputs
        self.episode, self.step, self.ended = 0, -1, True
        self.unhealthy = ""  # why the node serves no step now (its FMU hung), "" when healthy
        # why the node steps and resets for nobody now (a managed node not active), "" when active;
        # the one answer to "may this node step now" for native clients, ROS actions and /clock
        self.inactive = ""
        self.last_frame = b""
        self.last_action: tuple[int, bytes] = (0, b"")

    def plain(self, episode: int, step: int, client: int, values: Sequence[float], payload: bytes) -> bool:
        """Whether an action ``payload`` (no flags but SIGNED) from ``client`` is the next step of
        this episode, from the holder's session, in range: then it is served by a step, with no
        other rule to apply."""
        if episode != self.episode or step != self.step + 1 or self.ended or client < 0:
            return False
        if self.unhealthy or self.inactive:
            return False
        return self.lease.allows(client, payload) and self.check_inputs(values) is None

    def is_next(self, episode: int, step: int) -> bool:
        """Whether ``step`` of ``episode`` is still the next one (``plain`` checked, then locked)."""
        return episode == self.episode and step == self.step + 1 and not self.ended and not self.inactive

    def admit(
        self, client: int, values: Sequence[float], flags: int, state_refusal: str | None, payload: bytes
    ) -> Reject | None:
        """The checks that need no lock: the lease and the session, the values, the node's
        health, the flags."""
        if not self.lease.allows(client, payload):
            return Reject(NOT_HOLDER, self.lease.refusal(client))
        reason = self.check_inputs(values)
        if reason is not None:
            return Reject(OUT_OF_RANGE, reason)
        if self.unhealthy:
            return Reject(UNHEALTHY, self.unhealthy)
        if self.inactive:
            return Reject(INACTIVE, self.inactive)
        if flags & proto.SAVE_STATE and flags & proto.RESTORE_STATE:
            return Reject(STATE, "an action saves the state or restores it, not both")
        if flags & ~proto.SIGNED and state_refusal is not None:
            return Reject(STATE, state_refusal)
        return None

    def order(self, episode: int, step: int, flags: int, action: tuple[int, bytes]) -> Step | Reject:
        """What an admitted action for ``step`` of ``episode`` does now (called under the lock)."""
        if self.inactive:  # deactivated since it was admitted
            return Reject(INACTIVE, self.inactive)
        if episode != self.episode:
            return Reject(STALE, f"action for episode {episode}; the node is in {self.episode}")
        if flags & proto.RESTORE_STATE:
            return Step(restore=True)  # the step it names is the next one once restored
        if step == self.step and self.last_frame:
            if action != self.last_action:
                return Reject(CONFLICT, f"step {step} was already taken with another action or client")
            return RETRY
        return self.next(step, flags)

    def next(self, step: int, flags: int) -> Step | Reject:
        """Whether ``step`` may be stepped now (after a restore, too)."""
        if step != self.step + 1:
            return Reject(OUT_OF_ORDER, f"action for step {step}; next is {self.step + 1}")
        if self.ended:
            return Reject(ENDED, "the episode is over: reset first")
        return Step(save=True) if flags & proto.SAVE_STATE else ADVANCE

    def reject_key(self, reject: Reject, client: int, payload: bytes) -> bytes | None:
        """The key a REJECT of ``payload`` is signed with: the session's, once the action proved
        it comes from the holder; for ``not_holder`` none (the holder must not take a reject
        caused by a peer for its answer), or the key of a holder that was taken over, so that it
        learns so."""
        if reject.reason != NOT_HOLDER:
            return self.lease.key
        return self.lease.former_key(client, payload)

    # -- what happened: the node reports each outcome ------------------------------------------------
    def started(self, episode: int, frame: bytes) -> None:
        """A reset started ``episode``; ``frame`` is its step-0 answer."""
        self.episode, self.step, self.ended = episode, 0, False
        self.last_frame, self.last_action = frame, (0, b"")

    def restored(self, step: int) -> None:
        """The state saved before ``step`` is back: ``step`` is the next one."""
        self.step, self.ended, self.last_frame = step - 1, False, b""

    def stepped(
        self, action: tuple[int, bytes], values: list[float], time_ns: int, terminated: bool
    ) -> bytes:
        """One step was taken for ``action``: its OUTPUTS frame (kept to answer retries)."""
        flags = proto.TERMINATED if terminated else 0
        key = self.lease.key
        frame = proto.encode_values(
            proto.OUTPUTS, self.episode, self.step + 1, time_ns, values, flags=flags, key=key
        )
        self.step += 1
        self.ended = terminated
        self.last_frame, self.last_action = frame, action
        return frame

    def failed(self, action: tuple[int, bytes], detail: str, time_ns: int, hung: bool) -> bytes:
        """The step for ``action`` failed: the episode is over; its ERROR frame (kept to answer
        retries) at ``time_ns``, where the step started."""
        frame = self.error(detail, time_ns, hung)
        self.step += 1
        self.ended = True
        self.last_frame, self.last_action = frame, action
        return frame

    def error(self, detail: str, time_ns: int, hung: bool) -> bytes:
        """An ERROR frame for the next step (flagged HUNG: the model did not return in time)."""
        flags = proto.FAILED | (proto.HUNG if hung else 0)
        step, key = self.step + 1, self.lease.key
        return proto.encode_message(proto.ERROR, self.episode, step, time_ns, detail, flags=flags, key=key)
