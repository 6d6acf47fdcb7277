"""The states a :class:`~bridge.fmu.model.Model` restores at reset, and what ``auto`` trusts.

A reset by ``restore`` sets an FMU state snapshot taken right after initialisation, one per set
of parameters and start values (the most recent :data:`MAX_SNAPSHOTS`). ``auto`` never snapshots a
state it has not seen work: a fresh instance's initialisation is snapshotted at once; one after an
fmi reset only for value sets that recur, as a candidate kept once its episode has run a step
without terminating (:class:`ResetTrust`). Every FMU call goes through the model's backend.
"""

from __future__ import annotations

import ctypes
import logging
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Literal

from bridge.errors import FmuError
from bridge.fmu.backend import Backend
from bridge.fmu.spec import ResetPolicy

_log = logging.getLogger(__name__)

MAX_SNAPSHOTS = 8
# An FMU state and, for model exchange, the next time event it had announced (not part of the state).
Snapshot = tuple[ctypes.c_void_p, float | None]
Key = tuple[Any, ...]


@dataclass
class ResetTrust:
    """What ``reset_policy: auto`` has seen of the FMU's reset: a snapshot is taken of a fresh
    instance's initialisation, never of a state not yet seen to work. An fmi reset is trusted until
    an episode begun by it terminates at its first step where a fresh instance ran longer (the FMU
    kept its terminated flag); then ``auto`` re-instantiates instead."""

    origin: Literal["fresh", "fmi_reset", "restore"] = "fresh"  # how the current episode began
    fresh_steps: int | None = None  # steps of a fresh instance's episode that ended by termination
    fmi_reset_works: bool = True
    snapshots_work: bool = True  # get_state after an fmi reset succeeded (or was not tried)
    pending: tuple[Key, Snapshot] | None = None  # candidate snapshot after fmi reset


class Snapshots:
    """The snapshots of one model's instance by value set, and the trust ``auto`` has built."""

    def __init__(self, backend: Backend, model_name: str, policy: ResetPolicy, can_restore: bool) -> None:
        self.backend, self.model_name, self.policy = backend, model_name, policy
        self.taken = can_restore and policy in ("auto", "restore")  # whether snapshots are taken at all
        self.by_key: OrderedDict[Key, Snapshot | None] = OrderedDict()
        self.trust = ResetTrust()

    def get(self, key: Key) -> Snapshot | None:
        """The snapshot of ``key`` (moved to the most recent), or None."""
        snapshot = self.by_key.get(key)
        if snapshot is not None:
            self.by_key.move_to_end(key)
        return snapshot

    def distrust_reset(self, why: str) -> None:
        """The FMU's fmi reset is not to be trusted (``auto`` re-instantiates from now on)."""
        self.trust.fmi_reset_works = False
        if self.policy == "auto":
            fix = "re-instantiating instead (set reset_policy to restore or reinstantiate to say so)"
        else:
            fix = "episodes after a reset end at once: set reset_policy to auto, restore or reinstantiate"
        _log.warning("%s: the FMU %s; %s", self.model_name, why, fix)

    def judge_episode(self, steps: int, ended: bool) -> None:
        """``auto``: what the episode now ending (``steps`` FMU steps, ``ended`` by termination)
        shows; a candidate snapshot taken after an fmi reset is kept only if its episode ran a step
        without terminating."""
        trust = self.trust
        if trust.origin == "fresh" and ended:
            trust.fresh_steps = steps
        first_step_ended = trust.origin == "fmi_reset" and ended and steps <= 1
        longer_when_fresh = trust.fresh_steps is None or trust.fresh_steps > 1
        if first_step_ended and trust.fmi_reset_works and longer_when_fresh:
            ran = trust.fresh_steps if trust.fresh_steps is not None else "more"
            self.distrust_reset(
                f"asked to terminate at the first step after fmi reset, though a fresh instance ran "
                f"{ran} steps: its reset keeps a terminated run"
            )
        pending, trust.pending = trust.pending, None
        if pending is None:
            return
        key, snapshot = pending
        ran = steps > 1 or (steps == 1 and not ended)
        if trust.fmi_reset_works and trust.origin == "fmi_reset" and ran:
            self.by_key[key] = snapshot
            self.by_key.move_to_end(key)
            self._evict()
        else:
            self.backend.free_state(snapshot[0])

    def remember(self, key: Key, next_event_s: float | None) -> None:
        """Snapshot the state right after initialisation: ``restore`` always; ``auto`` after an
        initialisation of a fresh instance, and after an fmi reset for value sets that recur, as a
        candidate kept once its episode has run (:meth:`judge_episode`)."""
        if not self.taken or self.by_key.get(key) is not None:
            return
        if self.policy == "auto" and self.trust.origin != "fresh":
            if key not in self.by_key:
                self.by_key[key] = None  # first sighting: remember the key, a candidate on the next
                self._evict()
            elif self.trust.snapshots_work and (candidate := self._candidate(next_event_s)) is not None:
                self.trust.pending = (key, candidate)
            return
        self.by_key[key] = (self.backend.get_state(), next_event_s)
        self.by_key.move_to_end(key)
        self._evict()

    def _candidate(self, next_event_s: float | None) -> Snapshot | None:
        try:
            state = self.backend.get_state()
        except FmuError as exc:  # some FMUs refuse their state functions once fmi-reset
            _log.info("%s: no snapshot after fmi reset (%s)", self.model_name, exc)
            self.trust.snapshots_work = False
            return None
        return (state, next_event_s)

    def _evict(self) -> None:
        while len(self.by_key) > MAX_SNAPSHOTS:
            _, snapshot = self.by_key.popitem(last=False)
            if snapshot is not None:
                self.backend.free_state(snapshot[0])

    def drop(self) -> None:
        """Free every snapshot (the instance is about to go, or its states no longer apply)."""
        pending, self.trust.pending = self.trust.pending, None
        for snapshot in [*self.by_key.values(), pending[1] if pending else None]:
            if snapshot is not None:
                self.backend.free_state(snapshot[0])
        self.by_key.clear()
