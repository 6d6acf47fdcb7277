"""``BatchPlant``: N instances of one FMU, stepped together in one native call.

Each instance is a ``bridge.fmu.Model`` (instantiated, reset and restored exactly as in
``LocalFmuPlant``: the description's reset policy, snapshots of initial states); the instances are
a ``bridge.fmu.ModelBatch``, which owns every FMU call (the native loop, or the same FMI calls
from Python) and whose models keep the only clock. This plant adds episodes, samples, which
instances may step, and errors in the message shape of every plant; the env checks its task.

Errors are per instance: a failed instance gets a :class:`StepError` (same message shape as every
plant) in the step's ``errors`` and takes no further steps until it is reset; the others go on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError, FmuError, StepError
from bridge.fmu import Model, read_model_info, sha256
from bridge.fmu.batch import ModelBatch
from bridge.fmu.opening import open_model
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT
from bridge.plant.spec import PlantSpec

FloatArray = npt.NDArray[np.float64]


@dataclass
class BatchStep:
    """What one batch step returns: outputs per instance (rows of failed ones are stale),
    the instances whose FMU asked to terminate, and the errors of the instances that failed."""

    outputs: FloatArray
    terminated: npt.NDArray[np.bool_]
    errors: dict[int, StepError] = field(default_factory=dict)


class BatchPlant:
    """``n`` instances of the FMU ``spec`` describes, in this process.

    Args:
        spec: the model (FMU, step size, reset policy, ...) and what a sample is, as for
            ``LocalFmuPlant``; an experiment's from
            :func:`bridge.plant.experiment_model.experiment_plant_spec`.
        n: how many instances.
        threads: native threads stepping the batch (1: the calling thread only).
        native: use the native stepper (None: when it can be built and the signals allow it).
    """

    def __init__(self, spec: PlantSpec, n: int, *, threads: int = 1, native: bool | None = None) -> None:
        if n < 1 or threads < 1:
            raise ConfigError(
                f"a batch needs n >= 1 instances and threads >= 1, got n={n}, threads={threads}"
            )
        self.spec = spec
        self.fmu_path = spec.model.fmu
        self.timing = spec.timing
        self.name = f"FMU {self.fmu_path.name} (batch of {n})"
        self.n, self.threads = n, threads
        models: list[Model] = []
        try:
            for i in range(n):
                models.append(self._open(i))
            self.batch = ModelBatch(
                models, steps_per_sample=self.timing.steps_per_sample, threads=threads, native=native,
                name=self.name,
            )  # fmt: skip
        except BaseException:
            for model in models:
                model.close()
            raise
        self.info = models[0].info  # the array sizes after configuration mode
        self.episode = np.zeros(n, dtype=np.int64)
        self.sample = np.zeros(n, dtype=np.int64)
        self.ready = np.zeros(n, dtype=bool)  # reset and not failed since: may step

    def _open(self, i: int) -> Model:
        model_name = read_model_info(self.fmu_path).model_name
        return open_model(self.spec.model.replace(instance_name=f"{model_name}#batch{i}"))

    @property
    def models(self) -> list[Model]:
        """The instances (``bridge.fmu.Model``)."""
        return self.batch.models

    @property
    def k(self) -> npt.NDArray[np.int64]:
        """FMU steps since t0 per instance: the models' own clocks (read, do not write)."""
        return self.batch.clock

    @property
    def input_names(self) -> tuple[str, ...]:
        return self.batch.input_names

    @property
    def output_names(self) -> tuple[str, ...]:
        return self.batch.output_names

    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        """Fix the inputs ``step`` writes and the outputs it returns, in this order."""
        self.batch.bind(input_names, output_names)

    @property
    def native(self) -> bool:
        """Whether steps go through the native stepper (known after the first reset)."""
        return self.batch.native

    # -- episodes ---------------------------------------------------------------------------------
    def time_s(self, i: int) -> float:
        """Simulation time of instance ``i``'s last outputs, in seconds."""
        return self.batch.time_s(i)

    def reset(self, i: int, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        """Start a new episode of instance ``i`` (values: parameters, start values); its outputs at t0."""
        self.episode[i] += 1
        self.sample[i], self.ready[i] = 0, False
        try:
            outputs = self.batch.reset(i, values, inputs)
        except FmuError as exc:
            raise self._failed(i, exc, step=None) from exc
        self.ready[i] = True
        return outputs

    def step(self, inputs: FloatArray, active: npt.NDArray[np.bool_] | None = None) -> BatchStep:
        """One sample for every ready instance (``active`` narrows it) with ``inputs[i]`` held."""
        mask = self.ready if active is None else self.ready & active
        outcome = self.batch.step(inputs, mask)
        result = BatchStep(outcome.outputs, outcome.terminated)
        for i, exc in outcome.errors.items():
            result.errors[i] = self._failed(i, exc)
            self.ready[i] = False
        self.sample[mask] += 1
        self.ready[result.terminated] = False
        return result

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
        return {"fmu": str(self.fmu_path), "fmu_sha256": sha256(self.fmu_path), "node": ""}

    def close(self) -> None:
        """Free every instance (idempotent)."""
        self.batch.close()

    def __enter__(self) -> BatchPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
