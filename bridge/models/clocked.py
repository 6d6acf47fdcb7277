"""``clocks3``: our FMI 3.0 clock model, as a co-simulation (event mode), ME or scheduled-execution FMU.

Unlike the ``model.json`` models, ``models/clocks3/clocks3.c`` implements the FMI 3.0 functions itself
(event mode, ``fmi3SetClock``, intervals and shifts, ``fmi3ActivateModelPartition``), since the shared C
framework has no clocks that tick. This module writes its ``modelDescription.xml`` for either
interface, compiles the one source with gcc against FMPy's FMI headers and caches the archive as
:func:`bridge.models.example_fmu` does. What each clock does, with its ticks in closed form, is in the
comment at the top of the C file.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Final

from bridge.errors import ConfigError
from bridge.models.build import (
    CFLAGS,
    _compile,
    _find_gcc,
    _fmi_headers_dir,
    _write_zip,
    binary_path,
    cache_dir,
)
from bridge.models.sources import models_root

NAME: Final = "clocks3"
TOKEN: Final = "{5f0c1c3e-0c1f-4c55-9a0e-c10c4b3c1a03}"
VARIANTS: Final = ("cs", "me", "se")

# (name, value reference, XML attributes): one input Clock of each time-based kind, a triggered input
# and a triggered output Clock. The value references are those of clocks3.c.
_CLOCKS: Final = (
    ("c_ctrl", 1, 'intervalVariability="constant" intervalDecimal="0.1" shiftDecimal="0"'),
    ("c_const", 2, 'intervalVariability="constant" intervalDecimal="0.3" shiftDecimal="0.1"'),
    ("c_fixed", 3, 'intervalVariability="fixed" intervalDecimal="0.25" shiftDecimal="0.05"'),
    ("c_calc", 4, 'intervalVariability="fixed"'),
    ("c_tunable", 5, 'intervalVariability="tunable"'),
    ("c_changing", 6, 'intervalVariability="changing"'),
    ("c_countdown", 7, 'intervalVariability="countdown" clocks="2"'),
    ("trigger", 8, 'intervalVariability="triggered"'),
)
_DESCRIPTIONS: Final = {
    "c_ctrl": "the controller's clock: every 0.1 s from 0",
    "c_const": "constant: 0.1 + 0.3 k",
    "c_fixed": "fixed, interval given (the importer may set another in initialization mode): 0.05 + T k",
    "c_calc": "fixed, interval calculated by the FMU: period / 2 + period k",
    "c_tunable": "tunable: interval tunable_period, shift 0",
    "c_changing": "changing: intervals 0.1, 0.2, 0.3, ... from 0",
    "c_countdown": "countdown: 0.05 s after the start, then 0.05 s after each c_const tick",
    "trigger": "triggered input: when the importer activates it",
}


def model_description(interface: str) -> str:
    """``modelDescription.xml`` of the co-simulation (``"cs"``), model-exchange (``"me"``) or
    scheduled-execution (``"se"``) archive."""
    if interface == "cs":
        element = (
            f'<CoSimulation modelIdentifier="{NAME}" canHandleVariableCommunicationStepSize="true" '
            f'hasEventMode="true" canGetAndSetFMUState="true"/>'
        )
    elif interface == "me":
        element = f'<ModelExchange modelIdentifier="{NAME}" canGetAndSetFMUState="true"/>'
    else:
        element = f'<ScheduledExecution modelIdentifier="{NAME}" canGetAndSetFMUState="true"/>'
    variables = ['<Float64 name="time" valueReference="0" causality="independent" variability="continuous"/>']
    for priority, (name, vr, attributes) in enumerate(_CLOCKS):
        variables.append(
            f'<Clock name="{name}" valueReference="{vr}" causality="input" {attributes} '
            f'priority="{priority}" description="{_DESCRIPTIONS[name]}"/>'
        )
    variables.append(
        '<Clock name="c_out" valueReference="9" causality="output" intervalVariability="triggered" '
        'clocks="2" description="triggered output: every second c_const tick"/>'
    )
    variables += [
        '<Float64 name="x" valueReference="20" causality="output" variability="continuous" '
        'description="plant state: x\' = -x + u"/>',
        '<Float64 name="u" valueReference="21" causality="output" variability="discrete" clocks="1" '
        'description="controller output gain * (r - x), sampled on c_ctrl"/>',
        '<Float64 name="r" valueReference="22" causality="input" variability="continuous" start="1" '
        'description="set point"/>',
        '<Float64 name="gain" valueReference="23" causality="parameter" variability="fixed" start="2"/>',
        '<Float64 name="x0" valueReference="24" causality="parameter" variability="fixed" start="0"/>',
        '<Float64 name="period" valueReference="25" causality="parameter" variability="fixed" start="0.4" '
        'description="interval of c_calc (its shift is half of it)"/>',
        '<Float64 name="tunable_period" valueReference="26" causality="parameter" variability="tunable" '
        'start="0.5" description="interval of c_tunable"/>',
        '<Float64 name="alarm_time" valueReference="27" causality="parameter" variability="fixed" '
        'start="1.737" description="the FMU\'s own time event"/>',
        '<Float64 name="announce_alarm" valueReference="29" causality="parameter" variability="fixed" '
        'start="1" description="1: the FMU announces alarm_time as its next event time; 0: it does not"/>',
        '<Float64 name="t_alarm" valueReference="49" causality="output" variability="discrete" '
        'description="when the time event was handled (-1 before)"/>',
    ]
    if interface == "me":
        variables.append(
            '<Float64 name="der(x)" valueReference="28" causality="local" variability="continuous" '
            'derivative="20"/>'
        )
    names = [name for name, _, _ in _CLOCKS]
    for i, name in enumerate(names):
        variables.append(
            f'<Int32 name="n_{name.removeprefix("c_")}" valueReference="{31 + i}" causality="output" '
            f'variability="discrete" clocks="{i + 1}" description="ticks of {name}"/>'
        )
    variables.append(
        '<Int32 name="n_out" valueReference="39" causality="output" variability="discrete" clocks="9" '
        'description="ticks of c_out"/>'
    )
    for i, name in enumerate(names):
        variables.append(
            f'<Float64 name="t_{name.removeprefix("c_")}" valueReference="{41 + i}" causality="output" '
            f'variability="discrete" clocks="{i + 1}" description="time of the last tick of {name}"/>'
        )
    outputs = [9, 20, 21, *range(31, 40), *range(41, 50)]
    structure = "\n    ".join(f'<Output valueReference="{vr}"/>' for vr in outputs)
    if interface == "me":
        structure += '\n    <ContinuousStateDerivative valueReference="28"/>'

    body = "\n    ".join(variables)
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="{NAME}" instantiationToken="{TOKEN}"
  description="One input Clock of each time-based kind and a clocked controller">
  {element}
  <DefaultExperiment startTime="0" stopTime="3" stepSize="0.25"/>
  <ModelVariables>
    {body}
  </ModelVariables>
  <ModelStructure>
    {structure}
  </ModelStructure>
</fmiModelDescription>
"""


def clocks_fmu(interface: str = "cs", *, rebuild: bool = False) -> Path:
    """Path of the ``clocks3`` archive for ``interface`` (``"cs"``, ``"me"`` or ``"se"``), building it
    if needed.

    Raises:
        ConfigError: ``interface`` is neither.
        DependencyMissing: gcc or FMPy (for the FMI headers) is not installed.
        BridgeError: gcc failed; the message carries its output.
    """

    if interface not in VARIANTS:
        raise ConfigError(f"clocks3 is built as {VARIANTS}, not {interface!r}")
    source = models_root() / NAME / f"{NAME}.c"
    xml = model_description(interface)
    headers = _fmi_headers_dir()
    digest = hashlib.sha256()
    for part in (source.read_bytes(), xml.encode(), Path(__file__).read_bytes(), " ".join(CFLAGS).encode()):
        digest.update(part + b"\0")
    digest.update((headers / "fmi3Functions.h").read_bytes())
    target = cache_dir() / f"{NAME}-fmi3-{interface}-{digest.hexdigest()[:16]}.fmu"
    if target.is_file() and not rebuild:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".build-{NAME}-", dir=target.parent) as tmp:
        library = Path(tmp) / "library"
        command = [_find_gcc(), *CFLAGS, f"-I{headers}", "-o", str(library), str(source), "-lm"]
        _compile(command, f"{NAME} FMI 3.0 {interface.upper()}")
        partial = Path(tmp) / "archive.fmu"
        files = {
            "modelDescription.xml": xml.encode(),
            binary_path(NAME, "3.0"): library.read_bytes(),
            f"sources/{source.name}": source.read_bytes(),
        }
        _write_zip(partial, files)
        os.replace(partial, target)
    return target
