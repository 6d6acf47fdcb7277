"""The one exception family of fmu-bridge.

Every error a user can cause says what failed, what was expected, and how to fix it,
with paths and endpoints last. Third-party errors are wrapped at the boundary with
``raise ... from exc`` so the original traceback stays available.
"""

from __future__ import annotations

FMU_LOG_HEADER = "\nFMU log (most recent last):\n  "


class BridgeError(Exception):
    """Base class of every error raised by fmu-bridge."""


class ConfigError(BridgeError):
    """An experiment file or argument is invalid (names the key, the value and the file)."""


class FmuError(BridgeError):
    """An FMU could not be loaded, or an FMI call failed.

    Attributes:
        log: the FMU's own log messages captured around the failure (most recent last).
    """

    def __init__(self, message: str, *, log: list[str] | None = None) -> None:
        self.log = list(log or [])
        if self.log:
            message = message + FMU_LOG_HEADER + "\n  ".join(self.log[-20:])
        super().__init__(message)


class FmuLoadError(FmuError):
    """The FMU archive is unusable: not a zip, no model description, no binary for this platform."""


class VariableError(FmuError):
    """A variable name is unknown, or the variable cannot be read or written this way."""


class PlantError(BridgeError):
    """A plant could not complete a reset or a step.

    Every plant (an FMU in this process, in a child process, in a node, a system of FMUs)
    raises the same three subclasses with the same message shape: ``StepError`` (the model
    failed), ``StepTimeout`` (no answer within the deadline) and ``PlantDied`` (the process or
    node is gone). The episode is over after any of them; ``reset()`` starts a new one where
    the plant still lives.

    Attributes:
        plant: the plant's name (``FMU cartpole.fmu (in-process)``, ``node 'worker-1'``).
        episode: the episode number (1-based), or None before the first reset.
        step: the sample index the plant was stepping into, or None for a reset.
        time_s: simulation time at the failure, where known.
        detail: the cause in the plant's own words (the FMU's message and log).
        what: what failed, as the message names it (``the model hung``), and ``hint``: how to
            fix it; a system that reports a component's error keeps them where they are the
            component's own.
    """

    def __init__(
        self,
        message: str,
        *,
        plant: str = "",
        episode: int | None = None,
        step: int | None = None,
        time_s: float | None = None,
        detail: str = "",
        what: str = "",
        hint: str = "",
    ) -> None:
        self.plant = plant
        self.episode = episode
        self.step = step
        self.time_s = time_s
        self.detail = detail or message
        self.what, self.hint = what, hint
        BridgeError.__init__(self, message)  # not super(): FmuError would reset ``log``


class StepError(PlantError, FmuError):
    """The model failed: an FMI call returned Error/Fatal/Discard, or its outputs are not finite."""

    def __init__(
        self,
        message: str,
        *,
        step: int | None = None,
        time_s: float | None = None,
        log: list[str] | None = None,
        plant: str = "",
        episode: int | None = None,
        detail: str = "",
        what: str = "",
        hint: str = "",
    ) -> None:
        self.log = list(log or [])
        detail = detail or message
        if self.log:
            message = message + FMU_LOG_HEADER + "\n  ".join(self.log[-20:])
        PlantError.__init__(
            self,
            message,
            plant=plant,
            episode=episode,
            step=step,
            time_s=time_s,
            detail=detail,
            what=what,
            hint=hint,
        )


class StepTimeout(PlantError):
    """The plant did not answer a step or reset within its deadline (a hung FMU, a lost node)."""


class PlantDied(PlantError):
    """The plant is gone: its node's liveliness token disappeared, or its process exited."""


class StateFileError(ConfigError):
    """A saved FMU state is refused: the file is cut, corrupt, too large or not ours, it was saved
    by another FMU, or the FMU cannot serialise its state (canSerializeFMUstate)."""


class TransportError(BridgeError):
    """A network peer is unreachable, died, or sent something that is not our protocol."""


class DependencyMissing(BridgeError):
    """An optional dependency (rclpy, rerun, torch/SB3, ...) is not installed."""

    def __init__(self, package: str, purpose: str, install_hint: str) -> None:
        self.package = package
        super().__init__(
            f"{package} is needed for {purpose} but is not installed; install it with: {install_hint}"
        )
