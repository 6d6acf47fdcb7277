"""The long way of a lockstep action through a node, and every REJECT it sends.

:meth:`FmuNode.accept <bridge.net.node.FmuNode.accept>` admits an action and takes the node's
lock; :meth:`ActionPath.serve` then carries out what :class:`~bridge.net.lockstep.Lockstep`
orders: go back to the saved state first (RESTORE_STATE), answer a retry with the last frame
again, save the state (SAVE_STATE) and step, or reject with the reason. The rules are
``bridge.net.lockstep``'s; the state is ``bridge.net.node_state``'s; this module only wires them
to the node's step and its outputs publisher.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from typing import Any

from bridge.errors import PlantError
from bridge.net import lockstep as ls
from bridge.net import protocol as proto
from bridge.net.node_state import SavedState

_log = logging.getLogger("bridge.net.node")  # logged as the node's own
Action = tuple[int, bytes]  # the client id and the signed part of the action


class ActionPath:
    """Serves admitted lockstep actions of one node (called with the node's lock held).

    Args:
        advance: one step with the given inputs, its frame published.
        fail: answers a failed plant call with an ERROR frame.
        put: the node's outputs publisher's ``put``.
    """

    def __init__(
        self,
        lockstep: ls.Lockstep,
        saved: SavedState,
        counters: Counter[str],
        *,
        advance: Callable[[list[float], Action], Any],
        fail: Callable[[PlantError, Action], None],
        put: Callable[[bytes], Any],
        name: str,
    ) -> None:
        self.lockstep, self.saved, self.counters, self.name = lockstep, saved, counters, name
        self._advance, self._fail, self._put = advance, fail, put

    def serve(self, frame: proto.Frame, values: list[float], action: Action) -> None:
        """Restore, step, answer a retry or reject, as the lockstep rules order."""
        order = self.lockstep.order(frame.episode, frame.step, frame.flags, action)
        if isinstance(order, ls.Step) and order.restore:
            if not self._state(frame, self.saved.restore):
                return None
            self.lockstep.restored(frame.step)
            self.counters["restored"] += 1
            order = self.lockstep.next(frame.step, frame.flags & ~proto.RESTORE_STATE)
        if isinstance(order, ls.Reject):
            return self.reject(frame, order)
        if order.retry:
            self.counters["duplicate"] += 1  # a retry: the same answer again, never a second step
            self._put(self.lockstep.last_frame)
        elif not order.save or self._state(frame, self.saved.save):
            self._advance(values, action)
        return None

    def _state(self, frame: proto.Frame, change: Callable[[int, int], str | None]) -> bool:
        """Save or restore the state before ``frame``'s step; False: refused or failed (answered)."""
        try:
            reason = change(frame.episode, frame.step)
        except PlantError as exc:
            self._fail(exc, (frame.sim_time_ns, b""))
            return False
        if reason is not None:
            self.reject(frame, ls.Reject(ls.STATE, reason))
        return reason is None

    def reject(self, frame: proto.Frame, reject: ls.Reject, payload: bytes = b"") -> None:
        """Count, log and send a REJECT for ``frame`` (signed as ``Lockstep.reject_key`` says)."""
        self.counters[f"rejected_{reject.reason}"] += 1
        if _log.isEnabledFor(logging.INFO):
            _log.info("node %s rejected an action (%s): %s", self.name, reject.reason, reject.detail)
        key = self.lockstep.reject_key(reject, frame.sim_time_ns, payload)
        self._put(reject.frame(frame.episode, frame.step, frame.sim_time_ns, key))
