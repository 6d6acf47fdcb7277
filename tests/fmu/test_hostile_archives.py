"""Hostile FMU paths and archives: a FIFO, a device, a zip bomb, an absolute entry, links.

A FIFO once hung ``inspect``, ``init`` and ``check``; ``/dev/zero`` was read to gigabytes; a 4 GiB
zip bomb in ``resources/`` was extracted in full; an absolute entry and a symbolic link loop were
tracebacks. Each is now an FmuLoadError (exit code 2 on the command line) within seconds, and
nothing is written outside the extraction folder.
"""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import time
import zipfile
import zlib
from pathlib import Path

import pytest

from bridge.errors import FmuLoadError
from bridge.fmu import Model, archive, unzip
from bridge.models import example_fmu

CHUNK = 64 << 20  # one independently deflated block of zeros, repeated to make the bomb


def _cli(*args: str, cwd: Path) -> tuple[subprocess.CompletedProcess[str], float]:
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", *args],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        cwd=cwd,
        timeout=60,
        check=False,
    )
    return result, time.perf_counter() - started


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "model.fmu"
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("command", ["inspect", "init"])
def test_a_fifo_or_a_device_as_the_fmu_is_refused_within_seconds(fifo: Path, command: str) -> None:
    for path, kind in ((fifo, "a named pipe (FIFO)"), (Path("/dev/zero"), "a device")):
        extra = ["-o", str(fifo.parent / "out.yaml")] if command == "init" else []
        result, took_s = _cli(command, str(path), *extra, cwd=fifo.parent)
        assert result.returncode == 2, result.stderr
        assert f"is {kind}, not an FMU file" in result.stderr and "Traceback" not in result.stderr
        assert took_s < 30, took_s  # a new interpreter: about 2 s; a hang meets the 60 s timeout
    assert not (fifo.parent / "out.yaml").exists()


def test_check_with_a_fifo_as_model_fmu_ends_with_a_clear_error(fifo: Path) -> None:
    experiment = fifo.parent / "experiment.yaml"
    source = Path(__file__).resolve().parents[2] / "examples" / "dcmotor_tracking.yaml"
    experiment.write_text(source.read_text().replace("fmu: example:dcmotor", "fmu: model.fmu", 1))
    result, took_s = _cli("check", str(experiment), cwd=fifo.parent)
    assert result.returncode == 2, result.stderr
    assert "a named pipe (FIFO), not an FMU file" in result.stderr and took_s < 30  # as above


def _zip_entry(name: str, raw: bytes, size: int, crc: int, offset: int) -> tuple[bytes, bytes]:
    """A deflated entry's local header + data and its central directory record (zip64 not needed)."""
    encoded = name.encode()
    fields = (20, 0, 8, 0, 0x21, crc, len(raw), size, len(encoded))
    local = struct.pack("<IHHHHHIIIHH", 0x04034B50, *fields, 0) + encoded + raw
    central = struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, *fields, 0, 0, 0, 0, 0, offset) + encoded
    return local, central


def write_bomb(base: Path, out: Path, chunks: int) -> int:
    """``base`` plus ``resources/zeros.bin``: ``chunks`` x 64 MiB of zeros in a few MB; its size."""
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = compressor.compress(bytes(CHUNK)) + compressor.flush(zlib.Z_FULL_FLUSH)  # byte aligned
    raw = block * chunks + b"\x03\x00"  # an empty final block ends the stream
    crc = 0
    zeros = bytes(1 << 24)
    for _ in range(chunks * CHUNK // len(zeros)):
        crc = zlib.crc32(zeros, crc)
    entries = []
    with zipfile.ZipFile(base) as source:
        for info in source.infolist():
            data = source.read(info)
            packer = zlib.compressobj(6, zlib.DEFLATED, -15)
            entries.append(
                (info.filename, packer.compress(data) + packer.flush(), len(data), zlib.crc32(data))
            )
    entries.append(("resources/zeros.bin", raw, chunks * CHUNK, crc))
    body, directory = b"", b""
    for name, data, size, checksum in entries:
        local, central = _zip_entry(name, data, size, checksum, len(body))
        body, directory = body + local, directory + central
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(entries), len(entries), len(directory), len(body), 0)
    out.write_bytes(body + directory + end)
    return chunks * CHUNK


def test_a_4_gib_zip_bomb_in_resources_is_refused_before_a_byte_is_written(tmp_path: Path) -> None:
    bomb = tmp_path / "dcmotor.fmu"
    declared = write_bomb(example_fmu("dcmotor", "2.0", "cs"), bomb, chunks=63)
    assert declared > 4 * 10**9 and bomb.stat().st_size < 8 << 20
    with zipfile.ZipFile(bomb) as check:  # the bomb is a valid archive an independent reader opens
        assert check.getinfo("resources/zeros.bin").file_size == declared
    before = archive.extraction_count()  # other tests' open models may hold extractions
    started = time.perf_counter()
    with pytest.raises(
        FmuLoadError, match=rf"declares {declared + 1:,}|declares [\d,]+ bytes; at most"
    ) as caught:
        Model(bomb)
    assert time.perf_counter() - started < 10
    assert "zip bomb" in str(caught.value) and unzip.MAX_BYTES_ENV in str(caught.value)
    assert archive.extraction_count() == before


def test_extraction_counts_the_bytes_it_writes_within_a_lowered_limit(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fmu = example_fmu("dcmotor", "2.0", "cs")
    monkeypatch.setenv(unzip.MAX_BYTES_ENV, "1000")
    with pytest.raises(FmuLoadError, match=r"declares [\d,]+ bytes; at most 1,000 are extracted"):
        unzip.extract(fmu, tmp_path)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.delenv(unzip.MAX_BYTES_ENV)
    unzip.extract(fmu, tmp_path)
    assert (tmp_path / "modelDescription.xml").is_file()


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("/tmp/evil.txt", "an absolute path, a drive or a backslash"),
        ("resources/../../evil.txt", "climbs out of the archive"),
        ("C:/evil.txt", "an absolute path, a drive or a backslash"),
        ("resources\\evil.txt", "an absolute path, a drive or a backslash"),
    ],
)
def test_entries_that_leave_the_folder_are_refused(tmp_path: Path, entry: str, message: str) -> None:
    fmu = tmp_path / "m.fmu"
    with zipfile.ZipFile(example_fmu("dcmotor", "2.0", "cs")) as source, zipfile.ZipFile(fmu, "w") as out:
        for info in source.infolist():
            out.writestr(info, source.read(info))
        out.writestr(zipfile.ZipInfo(entry), b"evil")
    before = archive.extraction_count()  # other tests' open models may hold extractions
    with pytest.raises(FmuLoadError, match=message) as caught:
        Model(fmu)
    assert str(fmu) in str(caught.value) and not list(tmp_path.rglob("evil.txt"))
    assert archive.extraction_count() == before


def test_a_symbolic_link_entry_and_a_link_loop_are_refused(tmp_path: Path) -> None:
    fmu = tmp_path / "m.fmu"
    with zipfile.ZipFile(example_fmu("dcmotor", "2.0", "cs")) as source, zipfile.ZipFile(fmu, "w") as out:
        for info in source.infolist():
            out.writestr(info, source.read(info))
        link = zipfile.ZipInfo("resources/loop")
        link.external_attr = (0o120777 << 16) | 0x20  # S_IFLNK: a symbolic link to itself
        out.writestr(link, b"resources/loop")
    with pytest.raises(FmuLoadError, match="'resources/loop', a symbolic link; FMUs hold files only"):
        Model(fmu)
    loop = tmp_path / "loop.fmu"
    loop.symlink_to(loop)  # the FMU path itself is a link loop
    with pytest.raises(FmuLoadError, match=r"cannot read FMU|not found"):
        Model(loop)


def test_a_model_description_bomb_is_refused_before_it_is_read(tmp_path: Path) -> None:
    fmu = tmp_path / "m.fmu"
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = compressor.compress(bytes(CHUNK)) + compressor.flush(zlib.Z_FULL_FLUSH)
    size = 5 * CHUNK  # 320 MiB of zeros as the model description, in a few hundred KB
    raw = block * 5 + b"\x03\x00"
    local, central = _zip_entry("modelDescription.xml", raw, size, 0, 0)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 1, 1, len(central), len(local), 0)
    fmu.write_bytes(local + central + end)
    started = time.perf_counter()
    with pytest.raises(FmuLoadError, match=r"modelDescription.xml declares 335,544,320 bytes; at most"):
        Model(fmu)
    assert time.perf_counter() - started < 10
