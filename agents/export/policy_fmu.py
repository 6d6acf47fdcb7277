"""``fmu-bridge agent export fmu RUN --fmi 2|3``: a trained policy as a co-simulation FMU.

Inputs: when the observation is a plain selection of signals (outputs and references, history 1,
no tracking errors or last action), the FMU takes those signals in physical units, named after
them, and applies the Task's scaling itself; otherwise it takes the elements of the processed
observation vector (named after them, e.g. ``theta@t-1`` with history). Outputs: the plant's
action inputs in physical units. Sensor and actuator noise are training-time randomisation and
are left out, as in the deployed agent. The FMU is stateless: its outputs follow its inputs at
once (direct feedthrough), and ``doStep`` only advances time.
"""

from __future__ import annotations

import json
import logging
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from agents.export.ccode import InputScaling, model_c
from agents.export.extract import PolicyParts, load_parts
from bridge.errors import ConfigError
from bridge.models.build import build_archive, cache_key
from bridge.models.sources import models_root, units
from bridge.models.spec import TIME, Spec, Variable

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Named(Variable):
    """A variable whose C name is generated (FMI names such as ``theta@t-1`` are not C identifiers)."""

    c_ident: str = ""

    @property
    def c_name(self) -> str:
        return self.c_ident


def identifier(text: str) -> str:
    """A C identifier from an experiment name: ``policy_cartpole_continuous``."""
    return "policy_" + re.sub(r"\W", "_", text).strip("_").lower()


def signal_inputs(run: Path) -> tuple[list[str], InputScaling] | None:
    """Signal names and the Task's scaling when the observation is a plain selection, else None."""
    from agents.deploy import deployment_experiment, model_info_for
    from bridge.experiment.validate import timing
    from bridge.task.core import Task

    experiment, _ = deployment_experiment(run, None)
    section = experiment.observations
    if section.history != 1 or section.errors or section.include_action:
        return None
    run_dir = run if run.is_dir() else run.parent
    info = model_info_for(experiment, run_dir, None)
    observer = Task(experiment, info.variables, timing(experiment, info)).observer
    names = [*section.outputs, *section.references]
    # the Task's own scaling constants: the FMU must scale exactly as training did
    return names, InputScaling(observer._centre_list, observer._inv_list, section.clip)


def policy_spec(parts: PolicyParts, inputs: list[str], directory: Path, step_s: float) -> Spec:
    """The FMU's variables: one input per observation element or signal, one output per action input."""
    known = units()
    variables: list[Variable] = [TIME]

    def port(name: str, causality: str, ident: str, description: str) -> Variable:
        unit = parts.units.get(name) or None
        return _Named(
            vr=len(variables),
            name=name,
            type="Float64",
            causality=causality,
            variability="continuous",
            initial=None if causality == "input" else "calculated",
            description=description,
            start=0.0 if causality == "input" else None,
            unit=unit if unit in known else None,
            interfaces=("cs",),
            c_ident=ident,
        )

    for k, name in enumerate(inputs):
        variables.append(port(name, "input", f"in_{k}", f"observation {name}"))
    for k, name in enumerate(parts.input_names):
        variables.append(port(name, "output", f"out_{k}", f"action: plant input {name}"))
    return Spec(
        name=directory.name,
        directory=directory,
        description=f"{parts.algo} policy of experiment {parts.metadata['experiment']} (fmu-bridge)",
        variants=(("2.0", "cs"), ("3.0", "cs")),
        default_experiment={"startTime": 0.0, "stepSize": step_s},
        max_step_s=None,
        event_indicators=(),
        enums={},
        variables=tuple(variables),
    )


def export_fmu(run: Path, fmi: str = "2", out: Path | None = None) -> Path:
    """Generate the C, compile it with gcc and write the FMU (default ``RUN/policy-fmi<N>.fmu``)."""
    fmi_version = {"2": "2.0", "3": "3.0", "2.0": "2.0", "3.0": "3.0"}.get(fmi)
    if fmi_version is None:
        raise ConfigError(f"--fmi {fmi!r}: policy FMUs are FMI 2 or 3 co-simulation FMUs")
    parts, _ = load_parts(run)
    run_dir = run if run.is_dir() else run.parent
    out = out or run_dir / f"policy-fmi{fmi_version[0]}.fmu"
    selection = signal_inputs(run)
    inputs, scaling = selection if selection is not None else (parts.observation_names, None)
    name = identifier(str(parts.metadata["experiment"]))
    step_s = _sampling_time(run)
    with tempfile.TemporaryDirectory(prefix=".policy-fmu-") as tmp:
        directory = Path(tmp) / name
        directory.mkdir()
        (Path(tmp) / "common").symlink_to(models_root() / "common")
        spec = policy_spec(parts, inputs, directory, step_s)
        c_inputs = [v.c_name for v in spec.variables if v.causality == "input"]
        c_outputs = [v.c_name for v in spec.variables if v.causality == "output"]
        (directory / "model.c").write_text(model_c(parts, c_inputs, c_outputs, scaling), encoding="ascii")
        description = {**parts.metadata, "fmu_inputs": inputs, "inputs_are": _inputs_are(scaling)}
        (directory / "model.json").write_text(json.dumps(description, indent=2))
        out.parent.mkdir(parents=True, exist_ok=True)
        build_archive(spec, fmi_version, "cs", cache_key(spec, fmi_version, "cs"), out.resolve())
    _log.info("wrote %s", out)
    return out


def _inputs_are(scaling: InputScaling | None) -> str:
    if scaling is None:
        return "elements of the processed observation vector (the Task's scaling, errors, history)"
    return "signals in physical units (the FMU applies the Task's scaling)"


def _sampling_time(run: Path) -> float:
    from agents.deploy import deployment_experiment

    experiment, _ = deployment_experiment(run, None)
    return float(experiment.model.sampling_time or experiment.model.step_size or 0.01)
