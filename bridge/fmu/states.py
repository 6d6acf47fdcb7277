"""The continuous state vector of an initialised model-exchange instance.

For analysis above the FMU runtime (the linearisation of ``bridge.control``): read and set the
states and read their derivatives in the order of the model description's ``<Derivatives>``,
without ctypes or FMPy leaving ``bridge.fmu``.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError
from bridge.fmu.model import Model

FloatArray = npt.NDArray[np.float64]


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


class ContinuousStates:
    """The state vector of ``model`` (opened with ``interface="me"`` and initialised)."""

    def __init__(self, model: Model) -> None:
        if model.interface != "me":
            raise ConfigError(
                f"{model.info.model_name}: continuous states are set through model exchange; "
                f"open the model with interface='me'"
            )
        self.names = state_names(model)
        n = len(self.names)
        self._n = n
        self._x, self._dx = np.zeros(n), np.zeros(n)
        double_p = ctypes.POINTER(ctypes.c_double)
        self._x_ptr = self._x.ctypes.data_as(double_p)
        self._dx_ptr = self._dx.ctypes.data_as(double_p)
        fmu: Any = model._backend.fmu  # the FMPy object of this instance
        self._fmu = fmu
        self._get_dx = fmu.getContinuousStateDerivatives if model.info.fmi_major == 3 else fmu.getDerivatives

    def get(self) -> FloatArray:
        """The current states (a copy)."""
        self._fmu.getContinuousStates(self._x_ptr, self._n)
        return self._x.copy()

    def set(self, x: FloatArray) -> None:
        """Set every state (in :attr:`names` order)."""
        self._x[:] = x
        self._fmu.setContinuousStates(self._x_ptr, self._n)

    def derivatives(self) -> FloatArray:
        """The state derivatives at the current states, inputs and time (a copy)."""
        self._get_dx(self._dx_ptr, self._n)
        return self._dx.copy()
