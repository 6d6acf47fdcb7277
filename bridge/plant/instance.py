"""``FmuInstancePlant``: one FMU instance in this process as a plant.

What ``LocalFmuPlant`` (an FMU from its description) and a system's ``FmuComponent`` share: a sample
(inputs written, ``n`` FMU steps, outputs read) as one native call where the instance allows it
(``bridge.fmu.sample``, re-pointed after every reset), else through the model's signal groups
and ``Model.advance``; FMU errors turned into the plant's :class:`StepError`; and saving and
restoring the state through the Plant interface (a system's fixed-point iteration rolls
components back to the start of a macro step, here or in a node). Every FMU call is made by
``bridge.fmu``. ``LocalFmuPlant`` builds ``model``, ``info``, ``timing``, ``name`` and ``fmu_path``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bridge.errors import FMU_LOG_HEADER, BridgeError, FmuError, StepError, VariableError
from bridge.fmu import Model, ModelState, sha256
from bridge.fmu.sample import NativeSample
from bridge.fmu.signals import SignalGroup
from bridge.fmu.state_file import StateFile
from bridge.plant.base import (
    MODEL_FAILED,
    MODEL_FAILED_HINT,
    MODEL_INIT_FAILED,
    MODEL_INIT_FAILED_HINT,
    FloatArray,
    Plant,
)
from bridge.plant.spec import PlantSpec

_EMPTY = np.zeros(0)


@dataclass(frozen=True)
class SavedState:
    """What :meth:`FmuInstancePlant.save` returns."""

    model: ModelState
    sample: int
    terminated: bool


class FmuInstancePlant(Plant):
    """A plant over ``self.model``; ``bind`` binds the per-sample calls once (the hot path)."""

    can_set_values = True
    spec: PlantSpec
    model: Model
    fmu_path: Path
    _pending: Sequence[float] | None = None

    def _unbound(self, *_: Any) -> Any:
        raise BridgeError(f"{self.name}: bind() the plant to its input and output names first")

    _write: Any = _unbound
    _read: Any = _unbound
    _advance: Any = _unbound
    _n = 1
    _native: NativeSample | None = None
    _groups: tuple[SignalGroup | None, SignalGroup | None] | None = None

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        model = self.model
        try:
            inputs = model.signals(self.input_names, writable=True, role="input") if input_names else None
            outputs = model.signals(self.output_names, role="output") if output_names else None
        except BaseException:
            self.close()
            raise
        self._write = inputs.write if inputs is not None else _ignore
        self._read = outputs.read if outputs is not None else _empty
        self._advance, self._n = model.advance, self.timing.steps_per_sample
        self._groups = (inputs, outputs)
        self._native = None

    @property
    def native_stepping(self) -> bool:
        """True once samples run as one native call (``bridge.fmu.sample``)."""
        return self._native is not None

    @property
    def time_s(self) -> float:
        m = self.model  # Model.time_s inlined: read once per step on the hot path
        return m.start_time_s + m.step_index * m.step_size_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated = 0, False
        if self.spec.component is not None:
            # a system's component sets its own parameters and start values under those given (the
            # system's task does not know them); an experiment's task gives its model's itself
            values = {**self.spec.model.initial_values(), **values}
        try:
            self.model.reset(values)
            if inputs is not None:
                self._write(inputs)
            outputs: FloatArray = self._read()
        except StepError as exc:
            raise self._failed(exc, step=None) from exc
        except FmuError as exc:
            if isinstance(exc, VariableError) or not self.model.unusable:
                raise  # a name or value the model refuses before the FMU is asked: already clear
            raise self._init_refused(exc, values) from exc
        native = self._native  # a reset touches little: after an episode little is in the caches
        if native is not None:
            native.refresh()
        else:
            self._bind_native()
        return outputs

    def _init_refused(self, exc: FmuError, values: Mapping[str, Any]) -> StepError:
        """An FMU that refused to initialise: what it said, what this reset set, how to go on."""
        said = str(exc).partition(FMU_LOG_HEADER)[0]
        shown = [f"{k} = {v!r}" for k, v in list(values.items())[:10]]
        shown += [f"and {len(values) - 10} more"] if len(values) > 10 else []
        detail = f"{said}; this reset set {', '.join(shown) if shown else 'no values'}"
        hint = MODEL_INIT_FAILED_HINT
        # no time: the instance's clock is the last episode's until an initialisation completes
        return self.failure(StepError, MODEL_INIT_FAILED, detail, hint, step=None, time_s=None, log=exc.log)

    def _bind_native(self) -> None:
        """The one-call native sample where it applies, decided once the instance exists (reset
        re-points it at the instance afterwards); ``FMU_BRIDGE_NO_NATIVE=1`` keeps the Python path."""
        if self._groups is not None and not os.environ.get("FMU_BRIDGE_NO_NATIVE"):
            self._native = NativeSample.create(self.model, *self._groups, self._n)
            self._groups = None  # decided once

    def send(self, inputs: Sequence[float] | None) -> None:
        self._pending = inputs

    def receive(self) -> FloatArray:
        return self.step(self._pending)

    def step(self, inputs: Sequence[float] | None) -> FloatArray:
        native = self._native
        try:
            if native is not None:
                outputs: FloatArray = native(inputs)
                self.terminated = native.terminated
            else:
                if inputs is not None:
                    self._write(inputs)
                self.terminated = self._advance(self._n)
                outputs = self._read()
        except FmuError as exc:
            raise self._failed(exc) from exc
        self.sample += 1
        return outputs

    def _failed(self, exc: FmuError, **fields: Any) -> StepError:
        detail = exc.detail if isinstance(exc, StepError) else str(exc)
        return self.failure(StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, log=exc.log, **fields)

    def start_from(self, file: StateFile | None, source: str) -> None:
        """Start every episode from the next reset on at ``file``'s saved state (``Model.start_from``;
        None: initialise again)."""
        self.model.start_from(file, source)

    def set_values(self, values: Mapping[str, Any]) -> None:
        self.model.set(values)

    @property
    def unusable(self) -> str | None:
        if getattr(self.model, "unusable", False):
            return "the FMU's initialisation failed; the next reset instantiates it afresh"
        return None

    # -- saved states (rollback) -------------------------------------------------------------------
    @property
    def can_save(self) -> bool:
        """Whether :meth:`save` works: the FMU can get and set its state (FMI 2.0/3.0)."""
        return self.model.can_restore

    @property
    def save_refusal(self) -> str:
        if self.can_save:
            return ""
        return "the FMU cannot get and set its state (FMI 1.0, or canGetAndSetFMUstate is false)"

    def save(self) -> SavedState:
        """The state now: the model's, the sample index and the terminated flag."""
        try:
            return SavedState(self.model.save_state(), self.sample, self.terminated)
        except FmuError as exc:
            raise self._failed(exc) from exc

    def restore(self, saved: SavedState) -> None:
        """Back to ``saved`` (kept: restore it again, or :meth:`discard` it)."""
        try:
            self.model.restore_state(saved.model)
        except FmuError as exc:
            raise self._failed(exc) from exc
        self.sample, self.terminated = saved.sample, saved.terminated

    def discard(self, saved: SavedState) -> None:
        """Free ``saved``."""
        self.model.free_state(saved.model)

    def provenance(self) -> dict[str, str]:
        return {"fmu": str(self.fmu_path), "fmu_sha256": sha256(self.fmu_path), "node": ""}

    def close(self) -> None:
        model = getattr(self, "model", None)
        if model is not None:
            model.close()


def _ignore(_: Any) -> None:
    """Writing to a model without inputs."""


def _empty() -> FloatArray:
    return _EMPTY
