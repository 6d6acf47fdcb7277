"""``BatchPlant``: N instances of one FMU, stepped together in one native call.

Each instance is a ``bridge.fmu.Model`` (instantiated, reset and restored exactly as in
``LocalFmuPlant``: the experiment's reset policy, snapshots of initial states). A step writes
every active instance's inputs, advances one sample and reads its outputs; with the native
stepper (``native.py``) that is one foreign call for the whole batch with the GIL released,
optionally over several threads; without it (no compiler, or inputs/outputs that are not all
Float64) the same FMI calls are made from Python, with the same results.

Errors are per instance: a failed instance gets a :class:`StepError` (same message shape as every
plant) in the step's ``errors`` and takes no further steps until it is reset; the others go on.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError, FmuError, StepError
from bridge.experiment.config import Experiment
from bridge.experiment.validate import check_experiment, resolve_fmu, timing
from bridge.fmu import Model, read_model_info
from bridge.fmu.signals import SignalGroup
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT
from bridge.plant.batch import native as nat
from bridge.plant.batch.me import MeBatch
from bridge.plant.experiment_model import experiment_model

_log = logging.getLogger(__name__)
FloatArray = npt.NDArray[np.float64]


@dataclass
class BatchStep:
    """What one batch step returns: outputs per instance (rows of failed ones are stale),
    the instances whose FMU asked to terminate, and the errors of the instances that failed."""

    outputs: FloatArray
    terminated: npt.NDArray[np.bool_]
    errors: dict[int, StepError] = field(default_factory=dict)


class BatchPlant:
    """``n`` instances of the experiment's FMU in this process.

    Args:
        experiment: the experiment (its ``model`` section: FMU, step size, reset policy).
        n: how many instances.
        threads: native threads stepping the batch (1: the calling thread only).
        native: use the native stepper (None: when it can be built and the signals allow it).
    """

    def __init__(
        self, experiment: Experiment, n: int, *, threads: int = 1, native: bool | None = None
    ) -> None:
        if n < 1 or threads < 1:
            raise ConfigError(
                f"a batch needs n >= 1 instances and threads >= 1, got n={n}, threads={threads}"
            )
        self.experiment = exp = experiment
        self.fmu_path = resolve_fmu(exp)
        self.info = check_experiment(exp, read_model_info(self.fmu_path))
        self.timing = timing(exp, self.info)
        self.name = f"FMU {self.fmu_path.name} (batch of {n})"
        self.n, self.threads, self._want_native = n, threads, native
        self.models: list[Model] = []
        try:
            for i in range(n):
                self.models.append(self._open(i))
        except BaseException:
            self.close()
            raise
        self.input_names: tuple[str, ...] = ()
        self.output_names: tuple[str, ...] = ()
        self._inputs: list[SignalGroup] = []
        self._outputs: list[SignalGroup] = []
        self.k = np.zeros(n, dtype=np.int64)  # FMU steps since t0, per instance
        self.episode = np.zeros(n, dtype=np.int64)
        self.sample = np.zeros(n, dtype=np.int64)
        self.ready = np.zeros(n, dtype=bool)  # reset and not failed since: may step
        self._stepper: nat.NativeStepper | None = None
        self._spec: nat.BatchSpec | None = None
        self._me: MeBatch | None = None  # model exchange with a fixed-step solver
        self._comps = np.zeros(n, dtype=np.uintp)

    def _open(self, i: int) -> Model:
        return experiment_model(
            self.experiment, self.fmu_path, self.timing, f"{self.info.model_name}#batch{i}"
        )

    # -- binding ----------------------------------------------------------------------------------
    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        """Fix the inputs ``step`` writes and the outputs it returns, in this order."""
        self.input_names, self.output_names = tuple(input_names), tuple(output_names)
        self._inputs = [m.signals(self.input_names, writable=True, role="input") for m in self.models]
        self._outputs = [m.signals(self.output_names, role="output") for m in self.models]
        self._outputs_buf = np.zeros((self.n, len(self.output_names)))

    @property
    def native(self) -> bool:
        """Whether steps go through the native stepper (known after the first reset)."""
        return self._stepper is not None or self._me is not None

    def _setup_native(self) -> None:
        if self._want_native is False or self._spec is not None:
            return
        model = self.models[0]
        reason = self._native_refusal(model)
        stepper = nat.load() if reason is None and model.interface == "cs" else None
        if reason is None and model.interface == "me":
            self._spec = nat.BatchSpec()  # decided
            self._setup_me(model)
            return
        if stepper is None:
            if self._want_native:
                raise ConfigError(f"{self.name}: native stepping is not possible: {reason or 'no compiler'}")
            _log.info("%s: stepping in Python (%s)", self.name, reason or "no native stepper")
            self._spec = nat.BatchSpec()  # decided: Python
            return
        h = model.native_handles()
        vrs = self.info.variables
        self._in_vr = np.array([vrs[n].value_reference for n in self.input_names], dtype=np.uint32)
        self._out_vr = np.array([vrs[n].value_reference for n in self.output_names], dtype=np.uint32)
        self._spec = nat.BatchSpec(
            h["major"], h["set_real"], h["get_real"], h["do_step"], h["bool_status"],
            len(self._in_vr), self._in_vr.ctypes.data, len(self._out_vr), self._out_vr.ctypes.data,
            self.timing.start_time_s, self.timing.step_size_s, self.timing.steps_per_sample,
        )  # fmt: skip
        self._handles = {key: value for key, value in h.items() if key != "component"}
        self._stepper = stepper

    def _setup_me(self, model: Model) -> None:
        stepper = model.fixed_stepper
        assert stepper is not None  # _native_refusal checked the solver
        vrs = self.info.variables
        self._in_vr = np.array([vrs[n].value_reference for n in self.input_names], dtype=np.uint32)
        self._out_vr = np.array([vrs[n].value_reference for n in self.output_names], dtype=np.uint32)
        h = model.native_handles()
        self._handles = {key: h[key] for key in ("major", "set_real", "get_real")}
        self._me = MeBatch(
            h, in_vr=self._in_vr, out_vr=self._out_vr, timing=self.timing, substeps=stepper.substeps, n=self.n
        )

    def _native_refusal(self, model: Model) -> str | None:
        if self.info.fmi_major < 2 or (model.interface == "me" and model.fixed_stepper is None):
            return (
                f"it needs FMI 2.0/3.0 co-simulation, or model exchange with solver 'rk4' or 'euler'; "
                f"this is FMI {self.info.fmi_version} {model.interface} (solver {model.solver!r})"
            )
        names = [*self.input_names, *self.output_names]
        other = [n for n in names if self.info.variables[n].type != "Float64"]
        if other:
            return f"signals {other} are not Float64"
        discrete = [n for n in self.input_names if self.info.variables[n].variability != "continuous"]
        if model.interface == "me" and discrete:  # they are set in event mode, by the Python path
            return f"model-exchange inputs {discrete} are discrete"
        return None

    # -- episodes ---------------------------------------------------------------------------------
    def time_s(self, i: int) -> float:
        """Simulation time of instance ``i``'s last outputs, in seconds."""
        return self.timing.start_time_s + int(self.k[i]) * self.timing.step_size_s

    def reset(self, i: int, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        """Start a new episode of instance ``i`` (values: parameters, start values); its outputs at t0."""
        model = self.models[i]
        self.episode[i] += 1
        self.sample[i], self.k[i], self.ready[i] = 0, 0, False
        try:
            model.reset(values)
            if inputs is not None:
                self._inputs[i].write(inputs)
            outputs = self._outputs[i].read()
        except FmuError as exc:
            raise self._failed(i, exc, step=None) from exc
        self._setup_native()
        if self._me is not None:
            self._check_library(i, model.native_handles())
            self._me.bind(i, model)
        elif self._stepper is not None:
            handles = model.native_handles()
            self._check_library(i, handles)
            self._comps[i] = handles["component"]
        self.ready[i] = True
        return outputs

    def _check_library(self, i: int, handles: Mapping[str, int]) -> None:
        if any(handles[key] != value for key, value in self._handles.items()):
            raise ConfigError(f"{self.name}: instance {i} loaded another copy of the FMU's library")

    def step(self, inputs: FloatArray, active: npt.NDArray[np.bool_] | None = None) -> BatchStep:
        """One sample for every ready instance (``active`` narrows it) with ``inputs[i]`` held."""
        mask = self.ready if active is None else self.ready & active
        if self._me is not None:
            return self._step_me(np.ascontiguousarray(inputs, dtype=np.float64), mask)
        if self._stepper is not None:
            return self._step_native(np.ascontiguousarray(inputs, dtype=np.float64), mask)
        return self._step_python(inputs, mask)

    def _step_python(self, inputs: FloatArray, mask: npt.NDArray[np.bool_]) -> BatchStep:
        result = BatchStep(self._outputs_buf, np.zeros(self.n, dtype=bool))
        n = self.timing.steps_per_sample
        for i in np.flatnonzero(mask).tolist():
            model = self.models[i]
            try:
                self._inputs[i].write(inputs[i])
                result.terminated[i] = model.advance(n)
                self._outputs[i].read_into(result.outputs[i])
            except FmuError as exc:
                result.errors[i] = self._failed(i, exc)
                self.ready[i] = False
            self.k[i] = model.step_index
        self.sample[mask] += 1
        self._stop(result)
        return result

    def _step_native(self, inputs: FloatArray, mask: npt.NDArray[np.bool_]) -> BatchStep:
        assert self._stepper is not None and self._spec is not None
        status = np.empty(self.n, dtype=np.int32)
        self._stepper.step(
            self._spec,
            comps=self._comps,
            active=mask.view(np.uint8),
            inputs=inputs,
            outputs=self._outputs_buf,
            k=self.k,
            status=status,
            threads=self.threads,
        )
        result = BatchStep(self._outputs_buf, status == nat.TERMINATED)
        for i in np.flatnonzero((status > 1) & (status != nat.TERMINATED)).tolist():
            result.errors[i] = self._native_error(i, int(status[i]))
            self.ready[i] = False
        self.sample[mask] += 1
        self._stop(result)
        return result

    def _step_me(self, inputs: FloatArray, mask: npt.NDArray[np.bool_]) -> BatchStep:
        me = self._me
        assert me is not None
        result = BatchStep(self._outputs_buf, np.zeros(self.n, dtype=bool))
        if me.step(mask.view(np.uint8), inputs, self._outputs_buf, self.k, threads=self.threads):
            names = (self.input_names, self.output_names)
            for i in me.pending():  # events, termination, failures: finished as one instance would
                model = self.models[i]
                try:
                    result.terminated[i] = me.finish(i, model, self.k, names)
                    self._outputs[i].read_into(result.outputs[i])
                except FmuError as exc:
                    result.errors[i] = self._failed(i, exc)
                    self.ready[i] = False
        self.sample[mask] += 1
        self._stop(result)
        return result

    def _stop(self, result: BatchStep) -> None:
        self.ready[result.terminated] = False

    def _native_error(self, i: int, status: int) -> StepError:
        exc = nat.native_failure(self.models[i], status, int(self.k[i]), self.input_names, self.output_names)
        return self._failed(i, exc)

    def _failed(self, i: int, exc: FmuError, **fields: Any) -> StepError:
        detail = exc.detail if isinstance(exc, StepError) else str(exc)
        return self.failure(i, MODEL_FAILED, detail, log=exc.log, **fields)

    def failure(
        self, i: int, what: str, detail: str, *, log: list[str] | None = None, **fields: Any
    ) -> StepError:
        """A StepError for instance ``i`` in the message shape of every plant:
        ``<plant>: instance <i>: <what> at step <k> of episode <e> (t = <t> s): <detail>; <hint>``."""
        step = fields.pop("step", int(self.sample[i]) + 1)
        where = f" at step {step}" if step is not None else " at reset"
        time_s = self.time_s(i)
        message = (
            f"{self.name}: instance {i}: {what}{where} of episode {int(self.episode[i])} "
            f"(t = {time_s:g} s): {detail}; {MODEL_FAILED_HINT}"
        )
        return StepError(
            message, plant=self.name, episode=int(self.episode[i]), step=step, time_s=time_s,
            detail=detail, log=log,
        )  # fmt: skip

    # -- end ----------------------------------------------------------------------------------------
    def provenance(self) -> dict[str, str]:
        from bridge.fmu import sha256

        return {"fmu": str(self.fmu_path), "fmu_sha256": sha256(self.fmu_path), "node": ""}

    def close(self) -> None:
        """Free every instance (idempotent)."""
        models, self.models = getattr(self, "models", []), []
        for model in models:
            model.close()

    def __enter__(self) -> BatchPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
