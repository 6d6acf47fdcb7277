"""``strict_arrays``: an FMI 3.0 model that follows the standard's array rules to the letter.

Our other models share one C framework and a fixed layout; this one is written on its own
(``models/strict_arrays/strict_arrays.c``) because its array size is a structural parameter: ``n``
(UInt64, ``causality="structuralParameter"``, ``variability="fixed"``, start 3) sizes the input ``u``,
the state ``x`` and the output ``y[2, n]`` through ``<Dimension valueReference=...>``, and changes
only in configuration mode. Like a strict exporter, it answers any get or set whose ``nValues`` is
not the sum of the element counts of its value references with an error in the log and
``fmi3Error``. Co-simulation steps ``dx/dt = u - k x`` with its closed form
``x(t) = u/k + (x(t0) - u/k) exp(-k (t - t0))`` (``u`` held); model exchange leaves the
integration to the importer.

Example:
    >>> from bridge.models.strict import strict_arrays_fmu
    >>> path = strict_arrays_fmu()  # builds once, then returns the cached archive
"""

from __future__ import annotations

import hashlib
import tempfile
import uuid
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
      description="The sum of x"/>"""


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

    source = models_root() / NAME / f"{NAME}.c"
    key = _key(source)
    target = cache_dir() / f"{NAME}-fmi3-{key[:16]}.fmu"
    if target.is_file() and not rebuild:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    token = "{" + str(uuid.UUID(hex=key[:32])) + "}"
    with tempfile.TemporaryDirectory(prefix=f".build-{NAME}-", dir=target.parent) as tmp:
        library = Path(tmp) / "library"
        headers = build._fmi_headers_dir()
        command = [build._find_gcc(), *build.CFLAGS, f"-I{headers}", "-o", str(library), str(source), "-lm"]
        build._compile(command, f"{NAME} FMI 3.0")
        files = {
            "modelDescription.xml": model_description(token).encode(),
            build.binary_path(NAME, "3.0"): library.read_bytes(),
            f"sources/{source.name}": source.read_bytes(),
        }
        partial = Path(tmp) / "archive.fmu"
        build._write_zip(partial, files)
        partial.replace(target)  # atomic: readers see the old archive or the complete new one
    return target


def _key(source: Path) -> str:
    digest = hashlib.sha256()
    headers = build._fmi_headers_dir()
    for path in (source, Path(__file__), *(headers / h for h in build._FMI_HEADERS["3.0"])):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update(" ".join(build.CFLAGS).encode())
    return digest.hexdigest()
