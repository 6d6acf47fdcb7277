"""Reading recordings within absolute budgets: chunks, decompressed bytes, messages, time.

A 1 MB recording whose chunks each declared 32 MiB of tiny messages once took minutes and hundreds
of MB to ``info`` (the decompression budget grew with the file's size); a larger one ended in a
MemoryError traceback. Chunks compressed beyond any recording's ratio are now skipped unread, and
a read past its budget of decompressed bytes, messages or seconds is a RecordingError.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import zlib
from pathlib import Path

import pytest
import zstandard

from bridge.recording import records as rec
from bridge.recording.reader import read_recording
from bridge.recording.scan import Limits, Message, RecordingError, Scan

CHUNK = 32 << 20


def write_recording(path: Path, chunks: int, *, counting: bool, per_chunk: int = CHUNK) -> tuple[int, int]:
    """``chunks`` zstd chunks of ``per_chunk`` bytes of empty messages; (file size, messages).

    ``counting`` messages carry increasing sequence numbers and times (they compress like a real
    recording, about ten to one); otherwise they are identical (thousands to one: a bomb).
    """
    count = per_chunk // len(rec.message(1, 0, 0, 0, b""))
    schema = rec.schema(1, "sensor_msgs/msg/JointState", "ros2msg", b"")
    channel = rec.channel(1, 1, "/outputs", "cdr", {})
    parts = [rec.MAGIC, rec.header("ros2", "budget test"), schema, channel]
    same = b""
    for c in range(chunks):
        if same:  # identical chunks: compress once
            parts.append(same)
            continue
        base = c * count
        if counting:
            body = b"".join(rec.message(1, base + i, base + i, base + i, b"") for i in range(count))
        else:
            body = rec.message(1, 0, 1, 1, b"") * count
        data = zstandard.ZstdCompressor(level=3).compress(body)
        parts.append(
            rec.chunk(base, base + count, len(body), zlib.crc32(body), compression="zstd", data=data)
        )
        same = b"" if counting else parts[-1]
    path.write_bytes(b"".join(parts))
    return path.stat().st_size, count * chunks


@pytest.mark.parametrize("command", ["info", "export"])
def test_a_1_mb_file_declaring_gigabytes_of_tiny_messages_ends_in_seconds_not_minutes(
    tmp_path: Path, command: str
) -> None:
    bomb = tmp_path / "bomb.mcap"
    size, messages = write_recording(bomb, 300, counting=False)
    assert size < 1 << 20 and messages > 300_000_000
    extra = ["--csv", str(tmp_path / "out")] if command == "export" else []
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "bridge.cli", command, str(bomb), *extra],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        timeout=60,
        check=False,
    )
    took_s = time.perf_counter() - started
    output = result.stdout + result.stderr
    # a new interpreter and a refusal: a few seconds, more on a loaded machine; reading the
    # messages would take minutes
    assert took_s < 30, f"{command} took {took_s:.1f} s"
    assert "Traceback" not in output and result.returncode in (0, 2), output
    assert "1000 to one): corrupt, or a decompression bomb" in output, output


def test_the_message_budget_ends_a_read_with_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "many.mcap"
    _, messages = write_recording(path, 2, counting=True, per_chunk=1 << 20)
    read = [r for r in Scan(path).records() if isinstance(r, Message)]
    assert len(read) == messages  # all of them within the default budget
    with pytest.raises(
        RecordingError, match=rf"holds more than {messages // 2:,} messages: beyond"
    ) as caught:
        read_recording(path, Limits(messages=messages // 2))
    assert str(path) in str(caught.value)


def test_the_decompression_budget_is_absolute_not_a_share_of_the_file(tmp_path: Path) -> None:
    path = tmp_path / "inflating.mcap"
    write_recording(path, 3, counting=True, per_chunk=1 << 20)
    with pytest.raises(RecordingError, match=r"decompresses to more than 2,000,000 bytes"):
        read_recording(path, Limits(inflate_bytes=2_000_000))


def test_the_time_budget_ends_a_read_with_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "slow.mcap"
    write_recording(path, 1, counting=True, per_chunk=1 << 20)
    with pytest.raises(RecordingError, match=r"took longer than 0 s to read"):
        read_recording(path, Limits(time_s=0.0))


CAPPED = """
import os, resource, sys
from bridge.cli.main import main
import bridge.cli.recording, bridge.recording.reader, numpy, zstandard  # loaded before the cap

with open("/proc/self/statm") as statm:
    size = int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
cap = size + (int(sys.argv[1]) << 20)
resource.setrlimit(resource.RLIMIT_AS, (cap, resource.getrlimit(resource.RLIMIT_AS)[1]))
sys.argv = ["fmu-bridge", *sys.argv[2:]]
main()
"""


@pytest.fixture(scope="module")
def three_chunks(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """15 MB of recording that declares 96 MiB: three chunks of 32 MiB of counting messages."""
    path = tmp_path_factory.mktemp("memory") / "large.mcap"
    write_recording(path, 3, counting=True)
    return path


@pytest.mark.parametrize("spare_mb", [16, 96, 160])
@pytest.mark.parametrize("command", ["info", "export"])
def test_a_read_that_runs_out_of_memory_is_a_clear_error(
    tmp_path: Path, three_chunks: Path, command: str, spare_mb: int
) -> None:
    """A real MemoryError: the reader's process may take only ``spare_mb`` more address space
    (RLIMIT_AS) than it holds after loading. 16 MiB cannot hold one declared 32 MiB chunk (the
    decompression fails); 96 and 160 MiB run out while the messages are kept. Either way: the
    project's error and exit code 2, never a traceback, and no chunk called corrupt."""
    extra = ["--csv", str(tmp_path / "out")] if command == "export" else []
    result = subprocess.run(
        [sys.executable, "-c", CAPPED, str(spare_mb), command, str(three_chunks), *extra],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "400"},
        timeout=120,
        check=False,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert "Traceback" not in output and "corrupt" not in output, output
    assert "error: reading ran out of memory after" in output, output
    assert "raise the process's memory limit (ulimit -v)" in output and str(three_chunks) in output
