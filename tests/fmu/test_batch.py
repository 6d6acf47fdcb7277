"""ModelBatch: the batch keeps no clock of its own; each Model knows its time and its end.

Whichever path steps the instances (the native loop of ``batch.c``, the model-exchange batch
loop of ``fixed_step.c``, or Python through ``Model.advance``), each ``Model``'s step index and
time are the batch's, and an instance whose FMU asked to stop refuses to step, as a lone Model does.
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.errors import ConfigError, StepError
from bridge.fmu import Model, ModelBatch
from bridge.models import example_fmu

H = 0.1


def open_batch(version: str, n: int, native: bool, steps: int = 2) -> ModelBatch:
    models = [Model(example_fmu("typed", version, "cs"), step_size_s=H) for _ in range(n)]
    batch = ModelBatch(models, steps_per_sample=steps, native=native)
    batch.bind(["real_in"], ["real_out", "real_integral"])
    return batch


@pytest.mark.parametrize("native", [True, False])
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_each_model_keeps_the_batch_clock(version: str, native: bool) -> None:
    batch = open_batch(version, 3, native)
    try:
        for i in range(3):
            batch.reset(i, {}, [0.0])
        assert batch.native is native
        active = np.array([True, False, True])
        for u in (0.5, 0.25, 1.0):
            outcome = batch.step(np.full((3, 1), u), active)
            assert outcome.errors == {}
        assert batch.clock.tolist() == [6, 0, 6]
        assert [m.step_index for m in batch.models] == [6, 0, 6]
        assert [m.time_s for m in batch.models] == pytest.approx([0.6, 0.0, 0.6], abs=1e-12)
        assert [batch.time_s(i) for i in range(3)] == [m.time_s for m in batch.models]
        # the integral the FMU computed agrees with the time the models report
        np.testing.assert_allclose(outcome.outputs[[0, 2], 1], (0.5 + 0.25 + 1.0) * 2 * H, atol=1e-12)
        batch.reset(0, {}, [0.0])
        assert batch.clock.tolist() == [0, 0, 6] and batch.models[0].time_s == 0.0
        batch.models[2].advance(1)  # stepping a model alone moves the batch's view of it too
        assert batch.clock[2] == 7
    finally:
        batch.close()


@pytest.mark.parametrize("native", [True, False])
def test_a_model_whose_fmu_asked_to_stop_refuses_to_step(native: bool) -> None:
    batch = open_batch("2.0", 2, native)
    try:
        batch.reset(0, {}, [0.0])
        batch.reset(1, {"terminate_at_time": 0.3}, [0.0])
        both = np.array([True, True])
        assert batch.step(np.zeros((2, 1)), both).terminated.tolist() == [False, False]
        outcome = batch.step(np.zeros((2, 1)), both)
        assert outcome.terminated.tolist() == [False, True]
        stopped = batch.models[1]
        assert stopped.terminated and stopped.step_index == 3
        with pytest.raises(StepError, match="requested termination"):
            stopped.advance(1)
    finally:
        batch.close()


def test_a_batch_needs_models_and_threads() -> None:
    with pytest.raises(ConfigError, match="at least one model"):
        ModelBatch([], steps_per_sample=1)
