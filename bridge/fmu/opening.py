"""``open_model``: the one function that turns a :class:`bridge.fmu.spec.ModelSpec` into a ``Model``."""

from __future__ import annotations

from bridge.fmu import state_file
from bridge.fmu.model import Model
from bridge.fmu.spec import ModelSpec


def open_model(spec: ModelSpec) -> Model:
    """The model instance ``spec`` describes (not yet initialised): the one place model settings
    become ``Model`` arguments. With ``spec.state_file`` every episode starts from that state.

    Raises:
        ConfigError, FmuError, StateFileError: as :class:`bridge.fmu.Model` and
            :meth:`bridge.fmu.Model.start_from` raise them.
    """
    model = Model(
        spec.fmu,
        step_size_s=spec.step_size_s,
        start_time_s=spec.start_time_s,
        stop_time_s=spec.stop_time_s,
        interface=spec.interface,
        reset_policy=spec.reset_policy,
        tolerance=spec.tolerance,
        solver=spec.solver,
        solver_substeps=spec.solver_substeps,
        instance_name=spec.instance_name,
        structural_parameters=dict(spec.structural_parameters) or None,
        clock_intervals=dict(spec.clock_intervals),
        clock_schedule={k: list(v) for k, v in spec.clock_schedule},
    )
    if spec.state_file is not None:
        try:
            model.start_from(state_file.read(spec.state_file), str(spec.state_file))
        except BaseException:
            model.close()
            raise
    return model
