"""Strict test models, each written in C on its own, that behave as real exporters do where ours don't.

``strict_reset`` (FMI 2.0 CS, ``models/strict_reset/strict_reset.c``): its ``fmi2Reset`` keeps
the terminated flag of a finished run, and its state functions refuse an instance that was reset
(both selectable by the fixed parameter ``quirks``): what ``reset_policy: auto`` must survive.

``strict_arrays``: an FMI 3.0 model that follows the standard's array rules to the letter.

Our other models share one C framework and a fixed layout; this one is written on its own
(``models/strict_arrays/strict_arrays.c``) because its array size is a structural parameter: ``n``
(UInt64, ``causality="structuralParameter"``, ``variability="fixed"``, start 3) sizes the input ``u``,
the state ``x`` and the output ``y[2, n]`` through ``<Dimension valueReference=...>``, and changes
only in configuration mode. Like a strict exporter, it answers any get or set whose ``nValues`` is
not the sum of the element counts of its value references with an error in the log and
``fmi3Error``. Co-simulation steps ``dx/dt = u - k x`` with its closed form
``x(t) = u/k + (x(t0) - u/k) exp(-k (t - t0))`` (``u`` held); model exchange leaves the
integration to the importer. A fixed 2 x 2 parameter array ``A`` (identity until set) and the
local ``det_A``, its determinant, check that array parameters are set by element (``A[1,2]``)
with whole-array calls.

Example:
    >>> from bridge.models.strict import strict_arrays_fmu
    >>> path = strict_arrays_fmu()  # builds once, then returns the cached archive
"""

from __future__ import annotations

import hashlib
import tempfile
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Final

from bridge.models import build
from bridge.models.build import cache_dir
from bridge.models.sources import models_root

NAME: Final = "strict_arrays"
N_START: Final = 3
K_START: Final = 1.0

_VARIABLES: Final = f"""
    <Float64 name="time" valueReference="0" causality="independent" variability="continuous"
      description="Simulation time"/>
    <UInt64 name="n" valueReference="1" causality="structuralParameter" variability="fixed" start="{N_START}"
      description="Array size: the number of elements of u and x (set it in configuration mode)"/>
    <Float64 name="k" valueReference="2" causality="parameter" variability="fixed" start="{K_START}"
      description="Decay rate" unit="1/s"/>
    <Float64 name="u" valueReference="3" causality="input" start="1 2 3"
      description="Input array, u_i = i until set">
      <Dimension valueReference="1"/>
    </Float64>
    <Float64 name="x" valueReference="4" causality="local" variability="continuous" initial="exact"
      start="0.5 1 1.5" description="State array, x_i = 0.5 i at the start unless set">
      <Dimension valueReference="1"/>
    </Float64>
    <Float64 name="der(x)" valueReference="5" causality="local" variability="continuous" derivative="4"
      description="dx_i/dt = u_i - k x_i">
      <Dimension valueReference="1"/>
    </Float64>
    <Float64 name="y" valueReference="6" causality="output" variability="continuous"
      description="Row 1: x; row 2: der(x)">
      <Dimension start="2"/>
      <Dimension valueReference="1"/>
    </Float64>
    <Float64 name="total" valueReference="7" causality="output" variability="continuous"
      description="The sum of x"/>
    <Float64 name="A" valueReference="8" causality="parameter" variability="fixed" start="1 0 0 1"
      description="A 2 x 2 parameter array (identity until set); only its determinant is used">
      <Dimension start="2"/>
      <Dimension start="2"/>
    </Float64>
    <Float64 name="det_A" valueReference="9" causality="local" variability="fixed" initial="calculated"
      description="The determinant of A"/>"""


def model_description(token: str) -> str:
    """``modelDescription.xml``: model exchange and co-simulation in one archive."""
    identifier = f'modelIdentifier="{NAME}"'
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="{NAME}" instantiationToken="{token}"
  description="Strict FMI 3.0 arrays sized by a structural parameter" generationTool="fmu-bridge"
  variableNamingConvention="flat">
  <ModelExchange {identifier} canGetAndSetFMUState="true" needsCompletedIntegratorStep="false"/>
  <CoSimulation {identifier} canGetAndSetFMUState="true" canHandleVariableCommunicationStepSize="true"/>
  <UnitDefinitions><Unit name="1/s"><BaseUnit s="-1"/></Unit></UnitDefinitions>
  <DefaultExperiment startTime="0" stopTime="2" stepSize="0.1"/>
  <ModelVariables>{_VARIABLES}
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="6"/>
    <Output valueReference="7"/>
    <ContinuousStateDerivative valueReference="5"/>
    <InitialUnknown valueReference="6"/>
    <InitialUnknown valueReference="7"/>
    <InitialUnknown valueReference="5"/>
  </ModelStructure>
</fmiModelDescription>
"""


def strict_arrays_fmu(*, rebuild: bool = False) -> Path:
    """Path of the ``strict_arrays`` FMU (FMI 3.0, CS and ME), built with gcc on first use and cached
    beside the example models (see :func:`bridge.models.cache_dir`).

    Raises:
        DependencyMissing: gcc or FMPy (for the FMI headers) is not installed.
        BridgeError: gcc failed; the message carries its output.
    """
    return _built(NAME, "3.0", model_description, rebuild)


RESET_NAME: Final = "strict_reset"
RESET_T_END: Final = 1.0
KEEPS_TERMINATED: Final = 1
STATE_REFUSED_AFTER_RESET: Final = 2


def reset_model_description(guid: str) -> str:
    """``modelDescription.xml`` of ``strict_reset`` (FMI 2.0 co-simulation)."""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{RESET_NAME}" guid="{guid}"
  description="An FMI 2.0 model whose reset keeps its terminated flag and whose state functions
  refuse a reset instance" generationTool="fmu-bridge" variableNamingConvention="flat"
  numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{RESET_NAME}" canGetAndSetFMUstate="true"
    canHandleVariableCommunicationStepSize="true"/>
  <DefaultExperiment startTime="0" stopTime="{RESET_T_END}" stepSize="0.1"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"
      description="Input, 0 until set"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="k" valueReference="1" causality="parameter" variability="tunable"
      description="Decay rate"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="t_end" valueReference="2" causality="parameter" variability="fixed"
      description="The model asks to terminate at this time"><Real start="{RESET_T_END}"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="3" causality="output" variability="continuous"
      initial="exact" description="dx/dt = u - k x"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="quirks" valueReference="4" causality="parameter" variability="fixed"
      description="1: fmi2Reset keeps the terminated flag; 2: state functions refuse a reset instance">
      <Integer start="{KEEPS_TERMINATED | STATE_REFUSED_AFTER_RESET}"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="4"/></Outputs>
  </ModelStructure>
</fmiModelDescription>
"""


def strict_reset_fmu(*, rebuild: bool = False) -> Path:
    """Path of the ``strict_reset`` FMU (FMI 2.0 CS, ``models/strict_reset/strict_reset.c``): its
    ``fmi2Reset`` keeps the terminated flag of a finished run (parameter ``quirks`` bit 1) and its
    ``fmi2Get/SetFMUstate`` refuse an instance reset since instantiation (bit 2); both by default.
    It asks to terminate at ``t_end`` (1 s), so an episode is ``t_end / h`` steps when it is reset
    right. Built with gcc on first use and cached like :func:`strict_arrays_fmu`.
    """
    return _built(RESET_NAME, "2.0", reset_model_description, rebuild)


def _built(name: str, fmi_version: str, description: Callable[[str], str], rebuild: bool) -> Path:
    source = models_root() / name / f"{name}.c"
    key = _key(source, fmi_version)
    major = fmi_version.partition(".")[0]
    target = cache_dir() / f"{name}-fmi{major}-{key[:16]}.fmu"
    if target.is_file() and not rebuild:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    token = "{" + str(uuid.UUID(hex=key[:32])) + "}"
    with tempfile.TemporaryDirectory(prefix=f".build-{name}-", dir=target.parent) as tmp:
        library = Path(tmp) / "library"
        headers = build._fmi_headers_dir()
        command = [build._find_gcc(), *build.CFLAGS, f"-I{headers}", "-o", str(library), str(source), "-lm"]
        build._compile(command, f"{name} FMI {fmi_version}")
        files = {
            "modelDescription.xml": description(token).encode(),
            build.binary_path(name, fmi_version): library.read_bytes(),
            f"sources/{source.name}": source.read_bytes(),
        }
        partial = Path(tmp) / "archive.fmu"
        build._write_zip(partial, files)
        partial.replace(target)  # atomic: readers see the old archive or the complete new one
    return target


def _key(source: Path, fmi_version: str) -> str:
    digest = hashlib.sha256()
    headers = build._fmi_headers_dir()
    for path in (source, Path(__file__), *(headers / h for h in build._FMI_HEADERS[fmi_version])):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update(" ".join(build.CFLAGS).encode())
    return digest.hexdigest()
