"""The Plant interface: where physics stops and the task begins.

A plant serves one model (or a system of models) in sample-sized steps::

    plant.info, plant.timing               # what it serves: variables, step size, sampling time
    plant.bind(input_names, output_names)  # the signals the task writes and reads, once
    outputs = plant.reset(values, inputs)  # parameters/start values, inputs at t0 -> outputs at t0
    outputs = plant.step(inputs)           # hold inputs over one sample -> outputs at t_{k+1}
    plant.time_s, plant.terminated         # simulation time; the model asked to stop
    plant.close()

``step`` is ``send`` then ``receive``, so that a vector of plants in other processes or nodes
can all be sent their inputs before any answer is awaited (they then step in parallel); such a
plant says when ``receive`` would return at once (``answer_ready``) and sets an event its
caller gives when an answer may have arrived (``notify_answers``), so a vector env takes the
answers in the order they come. Three more things some plants can do, each with a default for
those that cannot: save, restore and discard their state (a system's fixed-point iteration rolls
its components back; the default refuses, saying why), and report each component's outputs (a
system of models, for the recorder; the default has no components).

One error semantics for every plant: a failed step raises :class:`StepError`, no answer in time
raises :class:`StepTimeout`, a plant that is gone raises :class:`PlantDied`, each built by
:meth:`Plant.failure` so the message reads the same whatever the plant.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError, PlantError
from bridge.experiment.validate import Timing
from bridge.fmu.vocab import ModelInfo

FloatArray = npt.NDArray[np.float64]
_NO_VALUES: FloatArray = np.zeros(0)
_NO_VALUES.flags.writeable = False
E = TypeVar("E", bound=PlantError)
MODEL_FAILED = "the model failed"
MODEL_INIT_FAILED = "the model's initialisation failed"
MODEL_INIT_FAILED_HINT = (
    "the FMU refused to initialise with the values this reset set (its log says why); reset with "
    "values it accepts (the experiment's ranges and scenarios); the next reset() instantiates it afresh"
)
MODEL_HUNG = "the model hung"  # a node's own deadline passed (its answer says so; not a lost answer)
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
    isolated: bool = False  # the model runs in a child process that a deadline can kill
    episode: int = 0  # episodes started by reset(), 1-based once running
    sample: int = 0  # samples stepped in this episode

    # -- the interface -----------------------------------------------------------------------------
    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        """Fix the input values ``step`` takes and the output values it returns, in this order."""
        self.input_names, self.output_names = tuple(input_names), tuple(output_names)

    @abstractmethod
    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
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

    # -- answers in the order they come (plants in other processes or nodes) ------------------------
    def answer_ready(self) -> bool:
        """Whether :meth:`receive` would return (or raise) at once. A plant that steps in
        ``receive`` itself (in this process) always is."""
        return True

    def notify_answers(self, event: threading.Event) -> None:
        """Set ``event`` too whenever an answer may have arrived (a vector env waits on one event
        for all its plants). A plant that answers in ``receive`` has nothing to announce."""
        return  # nothing arrives on its own: receive() computes the answer

    # -- saved states (a system's fixed-point iteration rolls its components back) ------------------
    @property
    def can_save(self) -> bool:
        """Whether :meth:`save`, :meth:`restore` and :meth:`discard` work."""
        return False

    @property
    def save_refusal(self) -> str:
        """Why this plant cannot save its state ("" where it can)."""
        return "" if self.can_save else "it does not save or restore its state"

    def save(self) -> Any:
        """The state now, to :meth:`restore` later; :meth:`discard` it when done."""
        raise self._cannot_save()

    def restore(self, saved: Any) -> None:
        """Back to ``saved`` (kept: restore it again, or discard it)."""
        raise self._cannot_save()

    def discard(self, saved: Any) -> None:
        """Free ``saved``."""
        raise self._cannot_save()

    def _cannot_save(self) -> ConfigError:
        return ConfigError(
            f"{self.name} cannot save and restore its state: {self.save_refusal}; iterate a system "
            "only over plants that can (FMI 2.0/3.0 FMUs with canGetAndSetFMUstate, in this process "
            "or on a lockstep node)"
        )

    # -- outputs again without a step (a system's feedthrough_outputs: updated) -----------------------
    can_settle: bool = False  # whether settle() works (a model in this process)

    def settle(self, inputs: Sequence[float]) -> FloatArray:
        """Set ``inputs`` at the current communication point and read the outputs again, without
        a step (direct feedthrough outputs then follow the inputs of this instant)."""
        raise ConfigError(
            f"{self.name} cannot set its inputs and read its outputs again between steps; run it in "
            "this process (system.feedthrough_outputs: updated needs that)"
        )

    # -- components (a system of models) -------------------------------------------------------------
    def component_outputs(self) -> dict[str, dict[str, float]]:
        """Each component's output values now, by component name (a system of models, for
        recording); a single model has no components: ``{}``."""
        return {}

    def component_values(self) -> FloatArray:
        """The values of :meth:`component_outputs`, flat in the same order (cheap, per step)."""
        return _NO_VALUES

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
            message,
            plant=self.name,
            episode=self.episode,
            step=step,
            time_s=time_s,
            detail=detail,
            what=what,
            hint=hint,
            **fields,
        )
