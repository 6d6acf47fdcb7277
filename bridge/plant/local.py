"""``LocalFmuPlant``: one FMU instance in this process (the fastest plant, and what nodes serve).

The only plant that imports the FMU runtime (``bridge.fmu``, hence FMPy). A step writes the
inputs through a typed ``SignalGroup``, advances ``n`` FMU steps (``sampling_time = n * h``)
and reads the outputs; FMU errors become :class:`StepError` with the FMU's own log.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bridge.errors import BridgeError, FmuError, StepError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, timing
from bridge.fmu import Model, read_model_info, sha256
from bridge.fmu.signals import SignalGroup
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant


class LocalFmuPlant(Plant):
    """The FMU of ``experiment`` (``model.fmu``), loaded and checked in this process.

    Args:
        experiment: the experiment whose ``model`` section says which FMU, interface, step size,
            reset policy and tolerance to use.
    """

    can_set_values = True

    def __init__(self, experiment: Experiment) -> None:
        self.experiment = exp = experiment
        self.fmu_path: Path = resolve_fmu(exp)
        self.info = check_experiment(exp, read_model_info(self.fmu_path))
        self.timing = t = timing(exp, self.info)
        self.name = f"FMU {self.fmu_path.name} (in-process)"
        self.model = Model(
            self.fmu_path,
            step_size_s=t.step_size_s,
            start_time_s=t.start_time_s,
            interface=exp.model.interface,
            reset_policy=exp.model.reset_policy,
            tolerance=exp.model.tolerance,
        )
        self._n = t.steps_per_sample
        self._inputs: SignalGroup | None = None
        self._outputs: SignalGroup | None = None
        self._pending: Sequence[float] | None = None
        self._write: Any = self._unbound
        self._advance: Any = self._unbound
        self._read: Any = self._unbound

    def _unbound(self, *_: Any) -> Any:
        raise BridgeError(f"{self.name}: bind() the plant to its input and output names first")

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        try:
            self._inputs = self.model.signals(self.input_names, writable=True, role="input")
            self._outputs = self.model.signals(self.output_names, role="output")
        except BaseException:
            self.close()
            raise
        # bound once: step() is the per-sample hot path
        self._write, self._advance, self._read = self._inputs.write, self.model.advance, self._outputs.read

    @property
    def time_s(self) -> float:
        m = self.model  # Model.time_s inlined: read once per step on the hot path
        return m.start_time_s + m.step_index * m.step_size_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        assert self._inputs is not None and self._outputs is not None, "bind() first"
        self.episode += 1
        self.sample, self.terminated = 0, False
        try:
            self.model.reset(values)
            if inputs is not None:
                self._inputs.write(inputs)
            return self._outputs.read()
        except StepError as exc:
            raise self._failed(exc, step=None) from exc

    def send(self, inputs: Sequence[float] | None) -> None:
        self._pending = inputs

    def receive(self) -> FloatArray:
        return self.step(self._pending)

    def step(self, inputs: Sequence[float] | None) -> FloatArray:
        try:
            if inputs is not None:
                self._write(inputs)
            self.terminated = self._advance(self._n)
            outputs: FloatArray = self._read()
        except FmuError as exc:
            raise self._failed(exc) from exc
        self.sample += 1
        return outputs

    def _failed(self, exc: FmuError, **fields: Any) -> StepError:
        detail = exc.detail if isinstance(exc, StepError) else str(exc)
        return self.failure(StepError, MODEL_FAILED, detail, MODEL_FAILED_HINT, log=exc.log, **fields)

    def set_values(self, values: Mapping[str, Any]) -> None:
        self.model.set(values)

    def current_inputs(self) -> list[float]:
        """The input values the FMU holds now (in ``input_names`` order)."""
        return [float(v) for v in self.model.get(self.input_names).values()]

    def provenance(self) -> dict[str, str]:
        return {"fmu": str(self.fmu_path), "fmu_sha256": sha256(self.fmu_path), "node": ""}

    def close(self) -> None:
        model = getattr(self, "model", None)
        if model is not None:
            model.close()
