"""Running a policy FMU from Python (through :class:`bridge.fmu.Model`): for checks and benchmarks."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.fmu import Model


class FmuPolicy:
    """A policy FMU, initialised and ready: ``act(values)`` sets its inputs and reads its outputs."""

    def __init__(self, path: Path) -> None:
        self.path = path
        with zipfile.ZipFile(path) as archive:
            self.description: dict[str, Any] = json.loads(archive.read("sources/model.json"))
        self.model = Model(path, interface="cs")
        self.model.initialize()
        self.input_names: list[str] = list(self.description["fmu_inputs"])
        self.output_names: list[str] = list(self.description["action_inputs"])
        self._inputs = self.model.signals(self.input_names, writable=True, role="policy input")
        self._outputs = self.model.signals(self.output_names, role="policy output")

    def act(self, values: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Input values in, the plant's input values out (no time step: outputs follow inputs)."""
        self._inputs.write(values)
        return self._outputs.read()

    def step(self) -> None:
        """Advance the FMU's time by one communication step (the policy itself holds no state)."""
        self.model.advance()

    def close(self) -> None:
        self.model.close()

    def __enter__(self) -> FmuPolicy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
