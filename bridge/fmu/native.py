"""Native helpers of the FMU runtime: a C source next to this module, built with gcc on first use.

The library is keyed by a hash of its source, the FMI headers it includes (FMPy's copy) and the
compiler flags, and moved into the per-user cache atomically, so parallel processes never load a
half-written file and an edit rebuilds. The cache root is ``$FMU_BRIDGE_CACHE``, else
``$XDG_CACHE_HOME/fmu-bridge`` (``~/.cache/fmu-bridge``), the example models' root.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from functools import cache
from pathlib import Path
from typing import Final

import fmpy

from bridge.errors import BridgeError, DependencyMissing

CFLAGS: Final = ("-shared", "-fPIC", "-O2", "-std=c99", "-Wall", "-pthread")
HEADERS: Final = ("fmi2FunctionTypes.h", "fmi2TypesPlatform.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")


def headers_dir() -> Path:
    """FMPy's copy of the FMI 2.0/3.0 headers."""
    directory = Path(fmpy.__file__).parent / "c-code"
    if not (directory / HEADERS[2]).is_file():
        raise BridgeError(
            f"FMPy's FMI headers are missing; expected {HEADERS[2]}; reinstall fmpy: {directory}"
        )
    return directory


def cache_root() -> Path:
    """``$FMU_BRIDGE_CACHE``, else ``$XDG_CACHE_HOME/fmu-bridge`` (``~/.cache/fmu-bridge``)."""
    root = os.environ.get("FMU_BRIDGE_CACHE")
    if root:
        return Path(root).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fmu-bridge"


def library_path(source: Path) -> Path:
    """Where ``source``'s library lives: ``<cache root>/native/<stem>-<hash>.so``."""
    digest = hashlib.sha256(source.read_bytes())
    headers = headers_dir()
    for name in HEADERS:
        digest.update(name.encode() + b"\0" + (headers / name).read_bytes())
    digest.update(" ".join(CFLAGS).encode())
    return cache_root() / "native" / f"{source.stem}-{digest.hexdigest()[:16]}.so"


def build(source: Path, target: Path) -> None:
    """Compile ``source`` into ``target`` (written next to it, then moved in place)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise DependencyMissing("gcc", f"the native helper {source.name}", "sudo apt-get install gcc")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".build-{source.stem}-", dir=target.parent) as tmp:
        partial = Path(tmp) / target.name
        command = [gcc, *CFLAGS, f"-I{headers_dir()}", "-o", str(partial), str(source), "-lm"]
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise BridgeError(
                f"gcc failed to build {source.name} (exit code {result.returncode}):\n"
                f"{result.stderr.strip()}\ncommand: {' '.join(command)}"
            )
        os.replace(partial, target)


@cache
def load(name: str) -> ctypes.CDLL:
    """The library of ``<name>.c`` (next to this module), built on first use.

    Raises:
        DependencyMissing: gcc is not installed.
        BridgeError: the build failed (gcc's output attached) or the library does not load.
    """
    source = Path(__file__).with_name(f"{name}.c")
    target = library_path(source)
    if not target.is_file():
        build(source, target)
    try:
        return ctypes.CDLL(str(target))
    except OSError as exc:
        raise BridgeError(f"the native helper {target} does not load ({exc}); delete it to rebuild") from exc
