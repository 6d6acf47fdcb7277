"""The names of an FMU's continuous states, in the order of its state vector (the model
description's ``<Derivatives>``), for analysis above the runtime (``bridge.control``) without
FMPy leaving ``bridge.fmu``; :meth:`Model.continuous_states` and its siblings read and set them."""

from __future__ import annotations

from bridge.errors import ConfigError
from bridge.fmu.model import Model


def state_names(model: Model) -> list[str]:
    """The FMU's continuous states in the order of its state vector."""
    from fmpy import read_model_description

    md = read_model_description(str(model.info.path))
    names = [u.variable.derivative.name for u in md.derivatives if u.variable.derivative is not None]
    if len(names) != model.info.number_of_states:
        raise ConfigError(
            f"{model.info.model_name}: the model description names {len(names)} state derivatives "
            f"but declares {model.info.number_of_states} continuous states"
        )
    return names


def derivative_pairs(model: Model) -> list[tuple[str, str]]:
    """(derivative, state) variable names of the model description's ``<Derivatives>``, in state
    vector order; empty where it lists none (optional in co-simulation)."""
    from fmpy import read_model_description

    md = read_model_description(str(model.info.path))
    return [
        (u.variable.name, u.variable.derivative.name)
        for u in md.derivatives
        if u.variable.derivative is not None
    ]
