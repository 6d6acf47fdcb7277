"""The Plant interface: where physics stops and the task begins.

A plant serves one model (or a system of models) in sample-sized steps::

    plant.info, plant.timing               # what it serves: variables, step size, sampling time
    plant.bind(input_names, output_names)  # the signals the task writes and reads, once
    outputs = plant.reset(values, inputs)  # parameters/start values, inputs at t0 -> outputs at t0
    outputs = plant.step(inputs)           # hold inputs over one sample -> outputs at t_{k+1}
    plant.time_s, plant.terminated         # simulation time; the model asked to stop
    plant.close()

``step`` is ``send`` then ``receive``, so that a vector of plants in other processes or nodes
can all be sent their inputs before any answer is awaited (they then step in parallel).

One error semantics for every plant: a failed step raises :class:`StepError`, no answer in time
raises :class:`StepTimeout`, a plant that is gone raises :class:`PlantDied`, each built by
:meth:`Plant.failure` so the message reads the same whatever the plant.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError, PlantError
from bridge.experiment.validate import Timing
from bridge.fmu.vocab import ModelInfo

FloatArray = npt.NDArray[np.float64]
E = TypeVar("E", bound=PlantError)
MODEL_FAILED = "the model failed"
MODEL_FAILED_HINT = (
    "check the model's parameters, the action bounds and the step size; reset() starts the next episode"
)


class Plant(ABC):
    """A model behind reset/step. Subclasses set ``name``, ``info`` and ``timing`` in ``__init__``."""

    name: str
    info: ModelInfo
    timing: Timing
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    terminated: bool = False
    can_set_values: bool = False  # whether set_values works between steps (hooks.state)
    episode: int = 0  # episodes started by reset(), 1-based once running
    sample: int = 0  # samples stepped in this episode

    # -- the interface -----------------------------------------------------------------------------
    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        """Fix the input values ``step`` takes and the output values it returns, in this order."""
        self.input_names, self.output_names = tuple(input_names), tuple(output_names)

    @abstractmethod
    def reset(self, values: Mapping[str, Any], inputs: Sequence[float]) -> FloatArray:
        """Start a new episode: set ``values`` (parameters, start values), write ``inputs``, and
        return the outputs at the start time."""

    @abstractmethod
    def send(self, inputs: Sequence[float] | None) -> None:
        """First half of a step: hand over the inputs held over the next sample (None: keep)."""

    @abstractmethod
    def receive(self) -> FloatArray:
        """Second half of a step: the outputs at the end of the sample."""

    def step(self, inputs: Sequence[float] | None) -> FloatArray:
        """Advance one sample with ``inputs`` held; the outputs at its end."""
        self.send(inputs)
        return self.receive()

    @property
    @abstractmethod
    def time_s(self) -> float:
        """Simulation time of the last outputs, in seconds."""

    def set_values(self, values: Mapping[str, Any]) -> None:
        """Change variables between steps (``hooks.state``); only some plants can."""
        raise ConfigError(
            f"{self.name} cannot change model variables between steps (hooks.state); "
            "run the experiment with the model in this process (FmuEnv)"
        )

    @property
    def unusable(self) -> str | None:
        """Why the model cannot step until the next reset (a failed initialisation, a dead or
        hung process), or None; a node's ``health`` may report it. The next reset starts afresh."""
        return None

    def provenance(self) -> dict[str, str]:
        """Where the model comes from, for recordings: ``fmu``, ``fmu_sha256``, ``node``."""
        return {"fmu": str(self.info.path), "fmu_sha256": "", "node": ""}

    def reset_info(self) -> dict[str, Any]:
        """Extra entries for the env's ``info`` at reset (for example the node's name)."""
        return {}

    @abstractmethod
    def close(self) -> None:
        """Release the model (idempotent)."""

    def __enter__(self) -> Plant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- one message shape for every failure --------------------------------------------------------
    def failure(self, kind: type[E], what: str, detail: str, hint: str = "", **fields: Any) -> E:
        """``kind`` with the message every plant uses:
        ``<plant>: <what> at step <k> of episode <e> (t = <t> s): <detail>; <hint>``."""
        step = fields.pop("step", self.sample + 1)
        where = f" at step {step}" if step is not None else " at reset"
        where += f" of episode {self.episode}" if self.episode else ""
        try:
            time_s: float | None = fields.pop("time_s", self.time_s)
        except PlantError:
            time_s = None
        if time_s is not None:
            where += f" (t = {time_s:g} s)"
        message = f"{self.name}: {what}{where}: {detail}"
        if hint:
            message += f"; {hint}"
        return kind(
            message, plant=self.name, episode=self.episode, step=step, time_s=time_s, detail=detail, **fields
        )
