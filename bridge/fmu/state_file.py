"""State files: an FMU's serialised state with a header that says whose state it is.

Layout (all integers little-endian)::

    8 bytes   magic b"FMUSTATE"
    2 bytes   format version (1)
    4 bytes   length L of the header (at most 64 KiB)
    L bytes   the header: UTF-8 JSON (fields of :class:`StateHeader`)
    N bytes   the FMU's own serialised state (fmi2SerializeFMUstate / fmi3SerializeFMUState);
              N is the header's ``size``

The header's ``sha256`` covers the header's values (its JSON with keys sorted, compact, and
``sha256`` empty) followed by the state, so a changed time or step index is caught as surely as a
changed state byte.

A reader never trusts a length it has not checked: the header length and the state's size are
weighed against a budget before anything is read, the file must end exactly after the state, and
the checksum must match, so a cut, padded or corrupted file is refused before the FMU sees a byte.
The header names the FMU (instantiation token / GUID, model identifier, FMI version, interface), so a
state is only ever handed to the FMU that made it.

The checksum detects damage, not intent: anyone can reseal a crafted file, and the FMU deserialises
the state's raw bytes, so a state file is as trusted as the FMU binary. For files that cross a
trust boundary, set a secret of your own in ``FMU_BRIDGE_STATE_KEY`` (or a file holding it in
``FMU_BRIDGE_STATE_KEY_FILE``): files written then carry ``mac``, an HMAC-SHA256 of their checksum
under that secret, and while a secret is set every file read without the right ``mac`` is refused
before the FMU sees it. This module imports no FMPy: the node and the
CLI read headers without loading an FMU.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import struct
import tempfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Final

from bridge.errors import StateFileError
from bridge.fmu.vocab import ModelInfo

MAGIC: Final = b"FMUSTATE"
FORMAT_VERSION: Final = 1
MAX_HEADER_BYTES: Final = 64 * 1024
#: Default budget for the FMU's serialised state; readers may pass another.
MAX_STATE_BYTES: Final = 256 * 1024 * 1024
_PREFIX: Final = struct.Struct("<8sHI")


@dataclass(frozen=True)
class StateHeader:
    """Whose state it is and where on the time grid it was saved.

    ``time_s`` is ``start_time_s + step_index * step_size_s``; ``start_values`` are the parameters
    and start values the FMU was initialised with (a state holds them, so they cannot change).
    """

    fmi_version: str
    model_name: str
    model_identifier: str
    instantiation_token: str
    interface: str
    time_s: float
    start_time_s: float
    step_size_s: float
    step_index: int
    terminated: bool
    next_event_s: float | None
    size: int
    sha256: str
    start_values: dict[str, Any] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    mac: str = ""  # HMAC-SHA256 of ``sha256`` under the user's state key ("": not signed)


@dataclass(frozen=True)
class StateFile:
    """A decoded state file: its header and the FMU's serialised state."""

    header: StateHeader
    payload: bytes = field(repr=False)


KEY_ENV: Final = "FMU_BRIDGE_STATE_KEY"
KEY_FILE_ENV: Final = "FMU_BRIDGE_STATE_KEY_FILE"
MIN_KEY_BYTES: Final = 16


def state_key() -> bytes | None:
    """The user's secret for state files (``FMU_BRIDGE_STATE_KEY``, else the content of the file
    ``FMU_BRIDGE_STATE_KEY_FILE``); None when neither is set."""
    text = os.environ.get(KEY_ENV, "")
    where = KEY_ENV
    if not text and os.environ.get(KEY_FILE_ENV):
        where = os.environ[KEY_FILE_ENV]
        try:
            text = Path(where).read_text().strip()
        except OSError as exc:
            raise StateFileError(f"cannot read the state key: {exc.strerror or exc} [{where}]") from exc
    if not text:
        return None
    key = text.encode()
    if len(key) < MIN_KEY_BYTES:
        raise StateFileError(
            f"the state key in {where} is {len(key)} bytes; use a secret of at least {MIN_KEY_BYTES} "
            "(e.g. `python -c 'import secrets; print(secrets.token_hex(32))'`)"
        )
    return key


def _mac(key: bytes, sha256: str) -> str:
    return hmac.new(key, b"fmu-bridge state v1\0" + sha256.encode(), hashlib.sha256).hexdigest()


def seal(header: StateHeader, payload: bytes) -> StateFile:
    """``header`` with the ``size`` and ``sha256`` of ``payload`` filled in (and ``mac`` when the
    user has a state key: :func:`state_key`), and the payload."""
    sized = replace(header, size=len(payload), sha256="", mac="")
    digest = _digest(sized, payload)
    key = state_key()
    return StateFile(replace(sized, sha256=digest, mac=_mac(key, digest) if key else ""), payload)


def encode(header: StateHeader, payload: bytes) -> bytes:
    """The bytes of a state file (``header`` as :func:`seal` made it for ``payload``)."""
    text = json.dumps(asdict(header), sort_keys=True, allow_nan=False).encode()
    if len(text) > MAX_HEADER_BYTES:
        raise StateFileError(f"the state header is {len(text)} bytes; at most {MAX_HEADER_BYTES} are allowed")
    return _PREFIX.pack(MAGIC, FORMAT_VERSION, len(text)) + text + payload


def _digest(header: StateHeader, payload: bytes) -> str:
    values = asdict(replace(header, sha256=""))
    values.pop("mac")  # the MAC covers the digest; files from before it existed keep theirs
    text = json.dumps(values, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode() + payload).hexdigest()


def _verified(header: StateHeader, payload: bytes, source: str) -> StateFile:
    try:
        intact = _digest(header, payload) == header.sha256
    except ValueError:  # a value JSON cannot hold (NaN, infinity): not a header we wrote
        intact = False
    if not intact:
        raise StateFileError(
            f"the saved state is corrupted: its SHA-256 does not match the header's; save it again [{source}]"
        )
    key = state_key()
    if key is not None and not hmac.compare_digest(header.mac, _mac(key, header.sha256)):
        what = "is not signed" if not header.mac else "is signed with another key"
        raise StateFileError(
            f"the state file {what}, and {KEY_ENV} is set: only files written with your key are "
            "loaded (a state is as trusted as the FMU binary: the FMU deserialises its bytes); save "
            f"it again with the key set, or unset {KEY_ENV} and {KEY_FILE_ENV} to load files you "
            f"trust without one [{source}]"
        )
    return StateFile(header, payload)


def decode(data: bytes, *, source: str = "the state", max_bytes: int = MAX_STATE_BYTES) -> StateFile:
    """A state file from its bytes (a file's content, or a message's); :class:`StateFileError`
    when it is cut, padded, corrupted, too large or not a state file."""
    header, start = _header(data[: _PREFIX.size + MAX_HEADER_BYTES], len(data), source, max_bytes)
    return _verified(header, data[start:], source)


def read(path: Path, *, max_bytes: int = MAX_STATE_BYTES) -> StateFile:
    """Read and check a state file; the sizes are checked before the state is read."""
    with _open(path) as f:
        head = f.read(_PREFIX.size + MAX_HEADER_BYTES)
        total = os.fstat(f.fileno()).st_size
        header, start = _header(head, total, str(path), max_bytes)
        f.seek(start)
        payload = f.read(header.size + 1)
    return _verified(header, payload, str(path))


def read_header(path: Path, *, max_bytes: int = MAX_STATE_BYTES) -> StateHeader:
    """Only the header (sizes checked, the state itself neither read nor verified)."""
    with _open(path) as f:
        head = f.read(_PREFIX.size + MAX_HEADER_BYTES)
        total = os.fstat(f.fileno()).st_size
    return _header(head, total, str(path), max_bytes)[0]


def write(path: Path, state: StateFile) -> None:
    """Write atomically: a reader sees the old file or the whole new one, never a part."""
    data = encode(state.header, state.payload)
    path = Path(path)
    tmp = ""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError as exc:
        if tmp:  # a failed write leaves no temporary file behind
            Path(tmp).unlink(missing_ok=True)
        raise StateFileError(
            f"cannot write the state file: {exc.strerror or exc}; free some space or write it "
            f"elsewhere [{path}]"
        ) from exc


def check_fits(header: StateHeader, info: ModelInfo, interface: str, source: str) -> None:
    """Refuse a state saved by another FMU (token, identifier, FMI version) or interface."""
    ours = {
        "instantiation token": info.guid,
        "model identifier": info.model_identifiers.get(interface, ""),
        "FMI version": info.fmi_version,
        "interface": interface,
    }
    theirs = {
        "instantiation token": header.instantiation_token,
        "model identifier": header.model_identifier,
        "FMI version": header.fmi_version,
        "interface": header.interface,
    }
    wrong = [f"{key} {theirs[key]!r} (this FMU: {ours[key]!r})" for key in ours if ours[key] != theirs[key]]
    if wrong:
        raise StateFileError(
            f"the state was saved by another FMU ({header.model_name}), not by {info.model_name}: "
            f"{'; '.join(wrong)}; save a state of this FMU with `fmu-bridge state save` [{source}]"
        )


def _open(path: Path) -> Any:
    try:
        return open(path, "rb")
    except OSError as exc:
        raise StateFileError(f"cannot read the state file: {exc.strerror or exc} [{path}]") from exc


def _header(head: bytes, total: int, source: str, max_bytes: int) -> tuple[StateHeader, int]:
    """The header from the file's first bytes, and where the state starts; sizes are checked
    against the budget and against ``total`` (the file's length)."""
    if len(head) < _PREFIX.size or head[:8] != MAGIC:
        raise StateFileError(
            f"not an fmu-bridge state file: expected it to start with {MAGIC!r}, got {head[:8]!r}; "
            f"save one with `fmu-bridge state save` [{source}]"
        )
    _, version, length = _PREFIX.unpack_from(head)
    if version != FORMAT_VERSION:
        raise StateFileError(
            f"state file format version {version} is not supported; this fmu-bridge reads version "
            f"{FORMAT_VERSION}; save the state again with this version [{source}]"
        )
    if length > MAX_HEADER_BYTES:
        raise StateFileError(
            f"the state file's header claims {length} bytes; at most {MAX_HEADER_BYTES} are allowed: "
            f"the file is corrupt or not ours [{source}]"
        )
    start = _PREFIX.size + length
    if len(head) < start:
        raise StateFileError(
            f"the state file is cut: its header needs {length} bytes, "
            f"{len(head) - _PREFIX.size} are there [{source}]"
        )
    header = _parse(head[_PREFIX.size : start], source)
    if header.size > max_bytes:
        raise StateFileError(
            f"the saved state is {header.size} bytes, more than the {max_bytes} allowed; raise the "
            f"limit only for a file you trust [{source}]"
        )
    if total != start + header.size:
        what = "cut" if total < start + header.size else "longer than its header says"
        raise StateFileError(
            f"the state file is {what}: expected {start + header.size} bytes, it has {total} [{source}]"
        )
    return header, start


def _parse(text: bytes, source: str) -> StateHeader:
    try:
        raw = json.loads(text.decode())
        if not isinstance(raw, dict):
            raise TypeError(f"a JSON object was expected, got {type(raw).__name__}")
        header = StateHeader(**raw)
        _check_types(header)
    except (UnicodeDecodeError, ValueError, TypeError) as exc:
        raise StateFileError(f"the state file's header is invalid ({exc}) [{source}]") from None
    return header


_TYPES: Final[dict[str, type | tuple[type, ...]]] = {
    "fmi_version": str,
    "model_name": str,
    "model_identifier": str,
    "instantiation_token": str,
    "interface": str,
    "time_s": (int, float),
    "start_time_s": (int, float),
    "step_size_s": (int, float),
    "step_index": int,
    "terminated": bool,
    "size": int,
    "sha256": str,
    "start_values": dict,
    "format_version": int,
    "mac": str,
}


def _check_types(header: StateHeader) -> None:
    for name, kind in _TYPES.items():
        value = getattr(header, name)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise TypeError(f"{name} has the wrong type ({type(value).__name__})")
    if header.size < 0 or header.step_index < 0 or header.step_size_s <= 0:
        raise ValueError("size and step_index must be >= 0 and step_size_s > 0")
    if header.next_event_s is not None and not isinstance(header.next_event_s, (int, float)):
        raise TypeError("next_event_s must be a number or null")
