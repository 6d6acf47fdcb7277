"""A node's saved FMU state: the SAVE_STATE and RESTORE_STATE flags of a lockstep action.

A system's fixed-point iteration repeats a macro step: the master's first pass asks each
component to save its state and then step, each further pass to go back to that state and step
again with new inputs (``bridge.plant.system.master``). Carried on the action itself, this
costs no round trip of its own, and components in several nodes still step in parallel.

The node keeps one saved state (a save replaces it; a reset and closing the node free it), so a
client cannot make it hold more memory. Flags are checked like every part of an action: only
the lease holder's actions get here, unknown flags make the payload malformed, and an action
the node cannot serve is rejected with the reason ``state``: a real-time node, an FMU that
cannot get and set its state (FMI 1.0, canGetAndSetFMUstate false, or an FMU isolated in a
child process), a restore with nothing saved, or one for another episode or step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from bridge.net import protocol as proto


class Rollback(Protocol):
    """A plant that can save and restore its state (``FmuInstancePlant``)."""

    @property
    def can_save(self) -> bool: ...

    def save(self) -> Any: ...

    def restore(self, saved: Any) -> None: ...

    def discard(self, saved: Any) -> None: ...


@dataclass
class _Saved:
    episode: int
    step: int
    state: Any


class SavedState:
    """The one saved state of a node's plant, and why the node cannot save one (if it cannot)."""

    def __init__(self, plant: Any, mode: str) -> None:
        self._plant: Rollback = plant
        self.refusal = _refusal(plant, mode)
        self._saved: _Saved | None = None

    @property
    def available(self) -> bool:
        return self.refusal is None

    def check(self, flags: int) -> str | None:
        """Why an action with state ``flags`` cannot be served now (None: it can)."""
        if flags & proto.SAVE_STATE and flags & proto.RESTORE_STATE:
            return "an action saves the state or restores it, not both"
        return self.refusal

    def save(self, episode: int, step: int) -> str | None:
        """Save the state before ``step`` of ``episode``, replacing any saved one; PlantError if
        the FMU fails to."""
        self.clear()
        self._saved = _Saved(episode, step - 1, self._plant.save())
        return None

    def restore(self, episode: int, step: int) -> str | None:
        """Go back to the state saved before ``step`` of ``episode``; the reason it cannot (None:
        done). PlantError if the FMU fails to."""
        saved = self._saved
        if saved is None:
            return "no state saved to restore: the first pass of a macro step saves it (SAVE_STATE)"
        if (saved.episode, saved.step + 1) != (episode, step):
            return (
                f"the saved state is from before step {saved.step + 1} of episode {saved.episode}, "
                f"not before step {step} of episode {episode}"
            )
        self._plant.restore(saved.state)
        return None

    def clear(self) -> None:
        """Free the saved state (before a reset, and when the node closes)."""
        saved, self._saved = self._saved, None
        if saved is not None:
            self._plant.discard(saved.state)


def _refusal(plant: Any, mode: str) -> str | None:
    if mode != "lockstep":
        return "a real-time node does not save or restore its state; serve the component in lockstep"
    if getattr(plant, "can_save", False):
        return None
    if getattr(plant, "isolated", False):
        return "the FMU runs isolated in a child process (--isolate or model.isolation); serve it without"
    return "the FMU cannot get and set its state (FMI 1.0, or canGetAndSetFMUstate is false)"
