"""Compiling an example FMU with gcc and zipping it into an ``.fmu`` archive, keyed for the cache.

The FMI headers come from FMPy's copy (found without importing FMPy: only ``bridge.fmu`` imports
it). Archives are written next to their final path and moved in place with :func:`os.replace`, so
parallel processes see either the old archive or the complete new one, never a half-written file.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import uuid
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Final

from bridge.errors import BridgeError, DependencyMissing
from bridge.models.ccode import c_header, c_table
from bridge.models.description import model_description
from bridge.models.spec import Spec

logger = logging.getLogger(__name__)

#: gcc flags; -fvisibility=hidden keeps everything but the FMI functions out of the symbol table.
CFLAGS: Final = ("-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-fvisibility=hidden")

_WRAPPERS: Final = {
    ("1.0", "cs"): "fmi1_cs.c",
    ("1.0", "me"): "fmi1_me.c",
    ("2.0", "cs"): "fmi2.c",
    ("2.0", "me"): "fmi2.c",
    ("3.0", "cs"): "fmi3.c",
    ("3.0", "me"): "fmi3.c",
}
_CORE_SOURCES: Final = ("fmu_core.c", "fmu_vars.c", "fmu_solver.c", "fmu_serial.c")
_FMI_HEADERS: Final = {
    "1.0": ("fmi1Functions.h",),
    "2.0": ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    "3.0": ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}


def cache_key(spec: Spec, fmi_version: str, interface: str) -> str:
    """sha256 over the model's and the framework's sources, the FMI headers, this generator and the flags."""
    digest = hashlib.sha256()
    headers = _fmi_headers_dir()
    generator = sorted(Path(__file__).resolve().parent.glob("*.py"))  # every module of bridge.models
    files = [*_source_files(spec), *generator, *(headers / h for h in _FMI_HEADERS[fmi_version])]
    for path in files:
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    digest.update(" ".join((spec.name, fmi_version, interface, *CFLAGS)).encode())
    return digest.hexdigest()


def build_archive(spec: Spec, fmi_version: str, interface: str, key: str, target: Path) -> None:
    """Generate the C and the XML, compile with gcc and atomically write the ``.fmu`` to ``target``.

    Raises:
        DependencyMissing: gcc or FMPy (for the FMI headers) is not installed.
        BridgeError: gcc failed; the message carries its output.
    """
    gcc, headers = _find_gcc(), _fmi_headers_dir()
    common = spec.directory.parent / "common"
    token = "{" + str(uuid.UUID(hex=key[:32])) + "}"
    with tempfile.TemporaryDirectory(prefix=f".build-{spec.name}-", dir=target.parent) as tmp:
        work = Path(tmp)
        (work / "model_gen.h").write_text(c_header(spec, fmi_version, interface, token), encoding="ascii")
        (work / "model_gen.c").write_text(c_table(spec, fmi_version, interface), encoding="ascii")
        sources = [
            *(common / s for s in _CORE_SOURCES),
            common / _WRAPPERS[fmi_version, interface],
            spec.c_source,
            work / "model_gen.c",
        ]
        library = work / "library"
        command = [
            gcc,
            *CFLAGS,
            f"-I{work}",
            f"-I{common}",
            f"-I{headers}",
            "-o",
            str(library),
            *(str(s) for s in sources),
            "-lm",
        ]
        _compile(command, f"{spec.name} FMI {fmi_version} {interface.upper()}")
        files = {
            "modelDescription.xml": model_description(spec, fmi_version, interface, token),
            binary_path(spec.name, fmi_version): library.read_bytes(),
            "sources/model_gen.h": (work / "model_gen.h").read_bytes(),
            "sources/model_gen.c": (work / "model_gen.c").read_bytes(),
        }
        for path in (
            *sources[:-1],
            common / "fmu_core.h",
            common / "fmu_types.h",
            spec.directory / "model.json",
        ):
            files[f"sources/{path.name}"] = path.read_bytes()
        partial = work / "archive.fmu"
        _write_zip(partial, files)
        os.replace(partial, target)  # atomic: readers see the old archive or the complete new one


def binary_path(name: str, fmi_version: str) -> str:
    """binaries/<platform>/<id>.<ext>: FMI 1.0/2.0 names (linux64) or FMI 3.0 tuples (x86_64-linux)."""
    system = {"linux": "linux", "darwin": "darwin", "win32": "windows"}.get(sys.platform, sys.platform)
    extension = {"linux": ".so", "darwin": ".dylib", "windows": ".dll"}.get(system, ".so")
    machine = platform.machine().lower()
    arch = "aarch64" if machine in ("aarch64", "arm64") else ("x86_64" if sys.maxsize > 2**32 else "x86")
    if fmi_version == "3.0":
        directory = f"{arch}-{system}"
    else:
        bits = "64" if arch in ("x86_64", "aarch64") else "32"
        directory = ("win" if system == "windows" else system) + bits
    return f"binaries/{directory}/{name}{extension}"


def _fmi_headers_dir() -> Path:
    """FMPy's copy of the FMI headers, found without importing FMPy (only bridge.fmu imports it)."""
    found = importlib.util.find_spec("fmpy")
    if found is None or found.origin is None:
        raise DependencyMissing("fmpy", "the FMI headers used to build the example FMUs", "pip install fmpy")
    directory = Path(found.origin).parent / "c-code"
    if not (directory / "fmi3Functions.h").is_file():
        raise BridgeError(
            f"FMPy's FMI headers are missing; expected fmi3Functions.h; reinstall fmpy: {directory}"
        )
    return directory


def _find_gcc() -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        raise DependencyMissing("gcc", "building the example FMUs", "sudo apt-get install gcc")
    return gcc


def _source_files(spec: Spec) -> list[Path]:
    common = spec.directory.parent / "common"
    files = {p for d in (common, spec.directory) for p in d.iterdir() if p.is_file()}
    return sorted(files | {spec.c_source})


def _compile(command: list[str], label: str) -> None:
    logger.debug("compiling %s: %s", label, " ".join(command))
    try:
        result = subprocess.run(command, capture_output=True, text=True, check=False)
    except FileNotFoundError as exc:
        raise DependencyMissing("gcc", "building the example FMUs", "sudo apt-get install gcc") from exc
    if result.returncode != 0:
        raise BridgeError(
            f"gcc failed to build {label} (exit code {result.returncode}); fix the C sources. gcc said:\n"
            f"{result.stderr.strip()}\ncommand: {' '.join(command)}"
        )
    if result.stderr.strip():
        logger.warning("gcc warnings while building %s:\n%s", label, result.stderr.strip())


def _write_zip(path: Path, files: Mapping[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(files):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, files[name])


def cache_dir() -> Path:
    """Where built archives are kept: ``$FMU_BRIDGE_CACHE/models``, else ``~/.cache/fmu-bridge/models``.

    ``FMU_BRIDGE_CACHE`` names the fmu-bridge cache root (shared with other cached downloads); the
    directory may be deleted at any time.
    """
    root = os.environ.get("FMU_BRIDGE_CACHE")
    if root:
        return Path(root).expanduser() / "models"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "fmu-bridge" / "models"
