"""``FmuComponent``: one FMU of a system in this process, a plant stepping one macro step a sample.

Like :class:`bridge.plant.local.LocalFmuPlant` but built from a component of a system rather than
an experiment: a macro step of ``H`` is ``n`` FMU steps of the component's own step size ``h``
(multi-rate, inputs held), and the state can be saved and restored (fixed-point iteration).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bridge.errors import ConfigError, FmuError, StepError
from bridge.experiment.validate import Timing
from bridge.fmu import Model, read_model_info, sha256
from bridge.fmu.signals import SignalGroup
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant
from bridge.plant.system.description import Component

_EMPTY = np.zeros(0)


def steps_per_macro(component: Component, macro_step_s: float, default_s: float | None, where: str) -> int:
    """How many steps of the component's own size make one macro step (must be whole)."""
    h = component.step_size_s or default_s or macro_step_s
    if h > macro_step_s * (1 + 1e-12):
        h = macro_step_s
    ratio = macro_step_s / h
    n = round(ratio)
    if n < 1 or not math.isclose(ratio, n, rel_tol=1e-9):
        raise ConfigError(
            f"system.components.{component.name}.step_size: {h} s does not divide the macro step "
            f"{macro_step_s} s (ratio {ratio:.6g}); choose {macro_step_s}/k{where}"
        )
    return n


class FmuComponent(Plant):
    """One component's FMU in this process; a sample is one macro step of ``macro_step_s``."""

    can_set_values = True

    def __init__(
        self, component: Component, macro_step_s: float, start_time_s: float, where: str = ""
    ) -> None:
        self.component = component
        self.info = read_model_info(component.fmu)
        self.name = f"component {component.name!r} ({component.fmu.name})"
        n = steps_per_macro(component, macro_step_s, None, where)  # default: one step per macro step
        self.timing = Timing(macro_step_s / n, n, macro_step_s, start_time_s)
        self.model = Model(
            component.fmu,
            step_size_s=macro_step_s / n,
            start_time_s=start_time_s,
            interface=component.interface,
            instance_name=component.name,
        )
        self._inputs: SignalGroup | None = None
        self._outputs: SignalGroup | None = None
        self._pending: Sequence[float] | None = None

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        model = self.model
        self._inputs = model.signals(self.input_names, writable=True, role="input") if input_names else None
        self._outputs = model.signals(self.output_names, role="output") if output_names else None

    @property
    def time_s(self) -> float:
        return self.model.time_s

    def _read(self) -> FloatArray:
        return self._outputs.read() if self._outputs is not None else _EMPTY

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        self.episode += 1
        self.sample, self.terminated = 0, False
        try:
            self.model.reset({**self.component.parameters, **values})
            self._write(inputs)
            return self._read()
        except FmuError as exc:
            raise self._failed(exc, step=None) from exc

    def _write(self, inputs: Sequence[float] | None) -> None:
        if inputs is not None and self._inputs is not None:
            self._inputs.write(inputs)

    def send(self, inputs: Sequence[float] | None) -> None:
        self._pending = inputs

    def receive(self) -> FloatArray:
        return self.step(self._pending)

    def step(self, inputs: Sequence[float] | None) -> FloatArray:
        try:
            self._write(inputs)
            self.terminated = self.model.advance(self.timing.steps_per_sample)
            outputs = self._read()
        except FmuError as exc:
            raise self._failed(exc) from exc
        self.sample += 1
        return outputs

    def _failed(self, exc: FmuError, **fields: Any) -> StepError:
        detail = exc.detail if isinstance(exc, StepError) else str(exc)
        return self.failure(StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, log=exc.log, **fields)

    def set_values(self, values: Mapping[str, Any]) -> None:
        self.model.set(values)

    # -- state for fixed-point iteration (the FMU's own get/set state) ------------------------------
    @property
    def can_save(self) -> bool:
        return self.model.can_restore

    def save(self) -> tuple[Any, int, int, bool]:
        backend = self.model._backend  # the FMU state functions are not part of Model's API
        return backend.get_state(), self.model.step_index, self.sample, self.terminated

    def restore(self, saved: tuple[Any, int, int, bool]) -> None:
        state, self.model.step_index, self.sample, self.terminated = saved
        self.model._backend.set_state(state)
        self.model.terminated = self.terminated

    def discard(self, saved: tuple[Any, int, int, bool]) -> None:
        self.model._backend.free_state(saved[0])

    def provenance(self) -> dict[str, str]:
        return {"fmu": str(self.component.fmu), "fmu_sha256": sha256(self.component.fmu), "node": ""}

    def close(self) -> None:
        model = getattr(self, "model", None)
        if model is not None:
            model.close()
