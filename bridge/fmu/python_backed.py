"""FMUs that run Python code in the process that loads them (pythonfmu, pythonfmu3 exports).

Such an FMU's binary starts the Python interpreter of the process it is loaded into and imports
its class from ``resources/``; the packages it imports must be installed there. Its exporter may
list them in ``resources/requirements.txt`` (pythonfmu copies project files into ``resources/``).
:func:`missing_requirements` names the ones this interpreter lacks, before anything is loaded,
instead of an instance that comes back NULL.

These FMUs are also fragile at exit (their embedded interpreter's teardown may abort, crash or
hang after a correct run), which is why :func:`bridge.plant.factory.fmu_plant` runs them in a
child process by default.
"""

from __future__ import annotations

import sys
import zipfile
from importlib import metadata
from pathlib import Path

from packaging.requirements import InvalidRequirement, Requirement

from bridge.errors import FmuLoadError
from bridge.fmu.vocab import ModelInfo

_MARKERS = ("resources/slavemodule.txt",)  # written by pythonfmu and pythonfmu3 beside the class
_REQUIREMENTS = "resources/requirements.txt"
_MAX_BYTES = 1 << 20  # a requirements file larger than this is not one


def is_python_backed(fmu_path: Path, generation_tool: str | None) -> bool:
    """Whether the FMU was exported by pythonfmu or pythonfmu3 (its tool name or its class file)."""
    if (generation_tool or "").lower().startswith("pythonfmu"):
        return True
    return any(_read(fmu_path, name) is not None for name in _MARKERS)


def requirements(fmu_path: Path) -> tuple[str, ...]:
    """The lines of the FMU's ``resources/requirements.txt`` (comments and options left out)."""
    text = _read(fmu_path, _REQUIREMENTS)
    if text is None:
        return ()
    lines = (line.split("#", 1)[0].strip() for line in text.splitlines())
    return tuple(line for line in lines if line and not line.startswith("-"))


def missing_requirements(info: ModelInfo) -> list[str]:
    """Each of ``info``'s Python requirements that this interpreter does not satisfy, with why."""
    missing = []
    for line in info.python_requirements:
        try:
            wanted = Requirement(line)
        except InvalidRequirement:
            continue  # not a package name (a URL, a path): pip's business, not ours to judge
        if wanted.marker is not None and not wanted.marker.evaluate():
            continue
        try:
            have = metadata.version(wanted.name)
        except metadata.PackageNotFoundError:
            missing.append(f"{line} (not installed)")
            continue
        if wanted.specifier and not wanted.specifier.contains(have, prereleases=True):
            missing.append(f"{line} ({have} installed)")
    return missing


def check_requirements(info: ModelInfo) -> None:
    """Raise :class:`FmuLoadError` naming every package the FMU's Python code lacks here."""
    if not info.python_backed:
        return
    missing = missing_requirements(info)
    if missing:
        names = " ".join(f"'{line.split(' (')[0]}'" for line in missing)
        raise FmuLoadError(
            f"{info.path.name} runs Python code that needs packages this Python does not have: "
            f"{', '.join(missing)} (from its resources/requirements.txt); install them with "
            f"`{sys.executable} -m pip install {names}` [{info.path}]"
        )


def _read(fmu_path: Path, name: str) -> str | None:
    if fmu_path.is_dir():
        path = fmu_path / name
        return path.read_text(errors="replace") if path.is_file() else None
    try:
        with zipfile.ZipFile(fmu_path) as archive:
            if archive.getinfo(name).file_size > _MAX_BYTES:
                return None
            return archive.read(name).decode(errors="replace")
    except (KeyError, OSError, zipfile.BadZipFile):
        return None
