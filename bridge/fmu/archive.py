"""Extract each FMU archive once per process and share the extraction between instances.

Re-instantiating a model, or opening a second instance of the same FMU, never unpacks the
archive again: extractions are reference counted and removed when the last user closes.
"""

from __future__ import annotations

import hashlib
import shutil
import tempfile
import threading
import zipfile
from dataclasses import dataclass
from pathlib import Path

from bridge.errors import FmuLoadError
from bridge.fmu import unzip

_LOCK = threading.Lock()
_EXTRACTIONS: dict[tuple[str, int, int], _Extraction] = {}


@dataclass
class _Extraction:
    directory: Path
    users: int
    owned: bool


def acquire(fmu_path: Path) -> Path:
    """Return the directory holding ``fmu_path`` extracted; extract it on first use.

    A directory path (an already extracted FMU) is returned as it is.
    """
    if fmu_path.is_dir():
        return fmu_path
    key = _key(fmu_path)
    with _LOCK:
        entry = _EXTRACTIONS.get(key)
        if entry is None:
            entry = _Extraction(directory=_extract(fmu_path), users=0, owned=True)
            _EXTRACTIONS[key] = entry
        entry.users += 1
        return entry.directory


def release(fmu_path: Path) -> None:
    """Drop one reference to the extraction of ``fmu_path``; the last one removes the files."""
    if fmu_path.is_dir():
        return
    key = _key(fmu_path)
    with _LOCK:
        entry = _EXTRACTIONS.get(key)
        if entry is None:
            return
        entry.users -= 1
        if entry.users <= 0:
            del _EXTRACTIONS[key]
            if entry.owned:
                shutil.rmtree(entry.directory, ignore_errors=True)


def extraction_count() -> int:
    """How many archives are extracted right now (for tests and diagnostics)."""
    with _LOCK:
        return len(_EXTRACTIONS)


def sha256(fmu_path: Path) -> str:
    """Hex SHA-256 of the archive (recorded with experiments so results name their model exactly)."""
    digest = hashlib.sha256()
    if fmu_path.is_dir():
        for file in sorted(p for p in fmu_path.rglob("*") if p.is_file()):
            digest.update(str(file.relative_to(fmu_path)).encode())
            digest.update(file.read_bytes())
        return digest.hexdigest()
    with fmu_path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _key(fmu_path: Path) -> tuple[str, int, int]:
    try:
        stat = fmu_path.stat()
    except OSError as exc:
        raise FmuLoadError(f"cannot read FMU: {exc.strerror} [{fmu_path}]") from exc
    return (str(fmu_path.resolve()), stat.st_size, stat.st_mtime_ns)


def _extract(fmu_path: Path) -> Path:
    target = Path(tempfile.mkdtemp(prefix=f"fmu-bridge-{fmu_path.stem}-"))
    try:
        unzip.extract(fmu_path, target)  # limits on size, count, paths and links
    except FmuLoadError:
        shutil.rmtree(target, ignore_errors=True)
        raise
    except (zipfile.BadZipFile, OSError, ValueError, NotImplementedError, EOFError) as exc:
        shutil.rmtree(target, ignore_errors=True)
        raise FmuLoadError(f"{fmu_path.name} could not be extracted: {exc} [{fmu_path}]") from exc
    return target
