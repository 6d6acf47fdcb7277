"""FMU archives opened with limits: regular files only, bounded extraction, no paths out.

An FMU is a zip file someone else made. A path that is a FIFO or a device (``/dev/zero``) would
block or be read without end; a zip bomb in ``resources/`` would fill the disk; an entry named
``/etc/x`` or ``../x`` would write outside the extraction folder; a symbolic link entry would point
anywhere. :func:`check_regular` refuses the first two before anything is opened, and
:func:`extract` writes entry by entry, counting the bytes actually decompressed (the sizes in the
archive's directory are claims, not facts), within :data:`MAX_ENTRIES` entries and
:data:`MAX_BYTES` bytes; ``FMU_BRIDGE_MAX_FMU_BYTES`` raises the byte limit for a genuinely large
model.
"""

from __future__ import annotations

import os
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from bridge.errors import FmuLoadError

MAX_ENTRIES = 100_000
MAX_BYTES = 2 << 30  # 2 GiB extracted; the largest FMUs in the wild carry a few hundred MB of tables
MAX_BYTES_ENV = "FMU_BRIDGE_MAX_FMU_BYTES"
MAX_DESCRIPTION_BYTES = 256 << 20  # the largest exported models' descriptions are tens of MB
_BLOCK = 1 << 20


def check_regular(path: Path) -> None:
    """Raise FmuLoadError unless ``path`` is a regular file or a directory (an extracted FMU)."""
    try:
        mode = path.stat().st_mode
    except OSError as exc:
        raise FmuLoadError(f"cannot read FMU: {exc.strerror} [{path}]") from None
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        kind = (
            "a named pipe (FIFO)"
            if stat.S_ISFIFO(mode)
            else "a device"
            if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket"
            if stat.S_ISSOCK(mode)
            else "not a regular file"
        )
        raise FmuLoadError(
            f"{path.name} is {kind}, not an FMU file: expected an .fmu archive or an extracted FMU "
            f"folder [{path}]"
        )


def check_description_size(fmu_path: Path, size: int) -> None:
    """Raise FmuLoadError if modelDescription.xml declares more than MAX_DESCRIPTION_BYTES: it is
    read whole into memory and parsed, so a bomb there would cost what it declares."""
    if size > MAX_DESCRIPTION_BYTES:
        raise FmuLoadError(
            f"{fmu_path.name}: modelDescription.xml declares {size:,} bytes; at most "
            f"{MAX_DESCRIPTION_BYTES:,} are read (a zip bomb, or a corrupt archive) [{fmu_path}]"
        )


def max_bytes() -> int:
    """The extraction byte limit: MAX_BYTES, or the environment's FMU_BRIDGE_MAX_FMU_BYTES."""
    text = os.environ.get(MAX_BYTES_ENV, "")
    try:
        return int(text) if text else MAX_BYTES
    except ValueError:
        raise FmuLoadError(f"{MAX_BYTES_ENV}={text!r} is not a whole number of bytes") from None


def extract(fmu_path: Path, target: Path) -> None:
    """Extract the archive ``fmu_path`` into the existing folder ``target`` within the limits."""
    check_regular(fmu_path)
    budget = _Budget(fmu_path, max_bytes())
    with zipfile.ZipFile(fmu_path) as archive:
        members = archive.infolist()
        if len(members) > MAX_ENTRIES:
            raise _refused(fmu_path, f"has {len(members):,} entries; at most {MAX_ENTRIES:,} are accepted")
        declared = sum(m.file_size for m in members)
        if declared > budget.limit:  # refused before a byte is written; the copy counts what is real
            raise _refused(
                fmu_path,
                f"declares {declared:,} bytes; at most {budget.limit:,} are extracted: a zip bomb, or a "
                f"model larger than the limit; set {MAX_BYTES_ENV} to allow more",
            )
        for member in members:
            relative = _relative(fmu_path, member)
            destination = target.joinpath(*relative.parts)
            if member.is_dir():
                destination.mkdir(parents=True, exist_ok=True)
                continue
            destination.parent.mkdir(parents=True, exist_ok=True)
            _copy(archive, member, destination, budget)


def _relative(fmu_path: Path, member: zipfile.ZipInfo) -> PurePosixPath:
    """The entry's path inside the archive, or FmuLoadError for one that could leave the folder."""
    name = member.filename
    path = PurePosixPath(name)
    if not path.parts or "\\" in name or "\0" in name or path.is_absolute() or ":" in path.parts[0]:
        raise _refused(fmu_path, f"has the entry {name!r}: an absolute path, a drive or a backslash")
    if ".." in path.parts:
        raise _refused(fmu_path, f"has the entry {name!r}, which climbs out of the archive with '..'")
    if stat.S_ISLNK(member.external_attr >> 16):
        raise _refused(fmu_path, f"has the entry {name!r}, a symbolic link; FMUs hold files only")
    return path


@dataclass
class _Budget:
    fmu_path: Path
    limit: int
    written: int = 0


def _copy(archive: zipfile.ZipFile, member: zipfile.ZipInfo, destination: Path, budget: _Budget) -> None:
    with archive.open(member) as source, destination.open("wb") as sink:
        while block := source.read(_BLOCK):
            budget.written += len(block)
            if budget.written > budget.limit:
                raise _refused(
                    budget.fmu_path,
                    f"expands to more than {budget.limit:,} bytes (at {member.filename!r}): a zip bomb, "
                    f"or a model larger than the limit; set {MAX_BYTES_ENV} to allow more",
                )
            sink.write(block)


def _refused(fmu_path: Path, what: str) -> FmuLoadError:
    return FmuLoadError(f"{fmu_path.name} was not extracted: the archive {what} [{fmu_path}]")
