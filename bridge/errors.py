"""The one exception family of fmu-bridge.

Every error a user can cause says what failed, what was expected, and how to fix it,
with paths and endpoints last. Third-party errors are wrapped at the boundary with
``raise ... from exc`` so the original traceback stays available.
"""

from __future__ import annotations


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
            message = message + "\nFMU log (most recent last):\n  " + "\n  ".join(self.log[-20:])
        super().__init__(message)


class FmuLoadError(FmuError):
    """The FMU archive is unusable: not a zip, no model description, no binary for this platform."""


class VariableError(FmuError):
    """A variable name is unknown, or the variable cannot be read or written this way."""


class StepError(FmuError):
    """An FMU step failed (error, fatal or discard status) at a known step index and time."""

    def __init__(
        self,
        message: str,
        *,
        step: int,
        time_s: float,
        log: list[str] | None = None,
    ) -> None:
        self.step = step
        self.time_s = time_s
        super().__init__(message, log=log)


class TransportError(BridgeError):
    """A network peer is unreachable, died, or sent something that is not our protocol."""


class StepTimeout(TransportError):
    """A remote node did not answer within the configured timeout."""


class DependencyMissing(BridgeError):
    """An optional dependency (rclpy, rerun, torch/SB3, ...) is not installed."""

    def __init__(self, package: str, purpose: str, install_hint: str) -> None:
        self.package = package
        super().__init__(
            f"{package} is needed for {purpose} but is not installed; install it with: {install_hint}"
        )
