"""Running a policy FMU from Python (through :class:`bridge.fmu.Model`): the deployed ``fmu`` runtime,
checks and benchmarks."""

from __future__ import annotations

import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from bridge.errors import ConfigError
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


def policy_fmu_file(path: Path) -> Path:
    """The given ``.fmu``, or the policy FMU of a run directory (``policy-fmi2.fmu`` before ``-fmi3``)."""
    if path.is_file() and path.suffix == ".fmu":
        return path
    run_dir = path if path.is_dir() else path.parent
    found = sorted(run_dir.glob("policy*.fmu"))
    if not found:
        raise ConfigError(
            f"{run_dir} has no policy FMU: export it first with `fmu-bridge agent export fmu {run_dir}` "
            "(on a machine with torch and gcc), then copy the run directory"
        )
    return found[0]


class FmuAgentPolicy:
    """The exported policy FMU as a deployed agent's policy (``agent run --runtime fmu``).

    It sees what the torch and ONNX runtimes see, the Task's observation and named signals, and
    gives the action the FMU computes: the FMU takes the signals in physical units when it was
    exported for a plain selection of signals (it scales them itself), else the elements of the
    Task's observation vector; its outputs are the plant's inputs in physical units, handed on
    exactly (:class:`~bridge.task.core.ExactAction`) or as the level they name (discrete).
    """

    def __init__(self, path: Path) -> None:
        self.path = policy_fmu_file(path)
        self.name = self.path.parent.name
        self.fmu = FmuPolicy(self.path)
        self._signals = str(self.fmu.description.get("inputs_are", "")).startswith("signals")
        self._task: Any = None
        self._continuous = False

    def reset(self, task: Any, seed: int | None) -> None:
        """Check that the FMU fits the task: the signals or observation size it reads, its outputs."""
        import gymnasium as gym

        names, outputs = self.fmu.input_names, self.fmu.output_names
        lacking = [n for n in names if n not in task.signal_names] if self._signals else []
        size = int(np.prod(task.observation_space.shape))
        if lacking or (not self._signals and len(names) != size) or outputs != list(task.action_inputs):
            raise ConfigError(
                f"{self.path} reads {names} and acts on {outputs}; the experiment observes "
                f"{size} values of {list(task.signal_names)} and acts on {list(task.action_inputs)}: "
                "deploy with the experiment of the run (its experiment.yaml)"
            )
        self._task, self._continuous = task, isinstance(task.action_space, gym.spaces.Box)

    def act(self, obs: Any, signals: Mapping[str, float]) -> Any:
        from bridge.task.core import ExactAction

        if self._signals:
            values: Any = [signals[n] for n in self.fmu.input_names]
        else:
            values = np.asarray(obs, dtype=np.float64).reshape(-1)
        physical = self.fmu.act(values).tolist()
        action = self._task.action_for_inputs(physical)
        return ExactAction(action, physical) if self._continuous else action

    def close(self) -> None:
        self.fmu.close()
