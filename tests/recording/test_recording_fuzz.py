"""Hostile recordings: a real recording cut at every byte, 1,000 seeded corruptions, decompression
bombs and a full disk. Every reader (``read_recording``, the ``info`` summary, CSV export,
``recover``, the CLI) must give a clear ``BridgeError`` or a partial read, never another
exception, with bounded memory; ``recover`` must never change its input. The counts go to
``recording_fuzz.json`` (see ``tests/reliability_table.py``)."""

from __future__ import annotations

import hashlib
import json
import os
import random
import resource
import shutil
import struct
import subprocess
import sys
import tempfile
import textwrap
import traceback
import zlib
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
import zstandard
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import BridgeError
from bridge.experiment.examples import example_experiment
from bridge.net.ros2 import cdr
from bridge.recording import meta
from bridge.recording import records as rec
from bridge.recording.env_recorder import record_env
from bridge.recording.export import describe, export_csv
from bridge.recording.reader import read_recording, recover_file
from bridge.recording.writer import McapWriter
from tests.conftest import Loopback, node_process
from tests.reliability_table import counts_file

ROOT = Path(__file__).resolve().parents[2]
COUNTS = counts_file("recording_fuzz.json")  # docs/reliability/ only on request (reliability_table.py)
SEED = 20260412
CORRUPTIONS = 1000
RSS_GROWTH_MB = 300  # what the whole fuzz run may add to the process's peak memory
runner = CliRunner()
_load_plugins()
TALLY: Counter[str] = Counter()


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real recording: two short cart-pole episodes through ``record_env`` over ``FmuEnv``."""
    folder = tmp_path_factory.mktemp("fuzz")
    env = record_env(FmuEnv(example_experiment("cartpole_continuous")), folder, "small", seed=1)
    env.action_space.seed(SEED)  # the same actions every run, so a failing corruption reproduces
    for episode in range(2):
        env.reset(seed=episode)
        for _ in range(5):
            env.step(env.action_space.sample())
    env.close()
    return folder / "small.mcap"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small recording written by the writer directly: two episodes of four steps on three
    channels, metadata and an attachment, in chunks of at most 400 bytes (so cuts fall between
    and inside chunks)."""
    path = tmp_path_factory.mktemp("tiny") / "tiny.mcap"
    with McapWriter(path, chunk_size=400) as writer:
        channels = meta.open_channels(
            writer, [meta.OUTPUTS, meta.REWARD, meta.EVENTS], {meta.OUTPUTS: ["x", "v"]}
        )
        writer.add_metadata("fmu_bridge", {"sampling_time_s": "0.02", "start_time_s": "0"})
        writer.add_attachment("experiment.yaml", "application/yaml", b"name: tiny\n")
        layout = cdr.JointStateLayout.of(["x", "v"])
        for episode in range(2):
            start = episode * 100_000_000
            event = {"event": "episode_start", "episode": episode, "seed": episode}
            writer.add_message(channels[meta.EVENTS], start, cdr.encode_string(json.dumps(event)))
            for k in range(4):
                log = start + k * 20_000_000
                writer.add_message(channels[meta.OUTPUTS], log, layout.pack(k * 20_000_000, [k, -k]))
                writer.add_message(channels[meta.REWARD], log, cdr.encode_float64(0.5 * k))
            end = {"event": "episode_end", "episode": episode, "steps": 4, "return": 3.0}
            writer.add_message(channels[meta.EVENTS], log, cdr.encode_string(json.dumps(end)))
            writer.flush()
    return path


@pytest.fixture()
def work(tmp_path: Path) -> Iterator[Path]:
    """A scratch folder in memory where there is one: the fuzz writes and syncs thousands of files."""
    shm = Path("/dev/shm")
    if not (shm.is_dir() and os.access(shm, os.W_OK)):
        yield tmp_path
        return
    folder = Path(tempfile.mkdtemp(prefix="fmu_bridge_fuzz_", dir=shm))
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def _outcome(path: Path, out: Path, recover: bool = True) -> tuple[str, int]:
    """Run every reader on ``path``: ("clean_error" | "partial" | "full", messages read)."""
    input_digest = hashlib.sha256(path.read_bytes()).hexdigest()
    try:
        recording = read_recording(path)
    except BridgeError:
        outcome, messages = "clean_error", 0
    else:
        json.dumps(describe(recording), default=str)
        export_csv(recording, out / "csv")
        messages = sum(recording.message_counts.values())
        outcome = "full" if recording.complete and not recording.problem_count else "partial"
    if not recover:
        return outcome, messages
    try:
        result = recover_file(path, out / "recovered.mcap", overwrite=True)
    except BridgeError:
        assert outcome == "clean_error", f"read gave {outcome}, recover failed"
    else:
        again = read_recording(result.path)  # what recover writes is always a clean file
        assert again.complete and not again.problem_count, again.problems
        assert sum(again.message_counts.values()) >= messages
    assert hashlib.sha256(path.read_bytes()).hexdigest() == input_digest, "recover changed its input"
    return outcome, messages


def _checked(
    path: Path, out: Path, failures: list[str], label: str, *, recover: bool = True
) -> tuple[str, int]:
    try:
        outcome, messages = _outcome(path, out, recover)
    except Exception:
        failures.append(f"{label}: {traceback.format_exc()}")
        TALLY["tracebacks"] += 1
        return "traceback", 0
    TALLY[outcome] += 1
    return outcome, messages


def _cli(path: Path, out: Path, failures: list[str], label: str) -> None:
    for args in (
        ["info", str(path)],
        ["info", str(path), "--json"],
        ["export", str(path), "--csv", str(out / "cli_csv")],
        ["recover", str(path), "-o", str(out / "cli.mcap"), "--force"],
    ):
        result = runner.invoke(app, args)
        TALLY["cli_runs"] += 1
        if result.exception is not None and not isinstance(result.exception, (BridgeError, SystemExit)):
            failures.append(f"{label} {args[0]}: {''.join(traceback.format_exception(result.exception))}")
            TALLY["tracebacks"] += 1


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _write_counts() -> None:
    counts = {
        "seed": SEED,
        "files_cut": TALLY["files_cut"],
        "cut_offsets": TALLY["cut_offsets"],
        "corruptions": TALLY["corruptions"],
        "corruption_kinds": {
            k.removeprefix("kind_"): v for k, v in sorted(TALLY.items()) if k.startswith("kind_")
        },
        "reader_runs": TALLY["clean_error"] + TALLY["partial"] + TALLY["full"] + TALLY["tracebacks"],
        "clean_errors": TALLY["clean_error"],
        "partial_reads": TALLY["partial"],
        "full_reads": TALLY["full"],
        "cli_runs": TALLY["cli_runs"],
        "bombs": TALLY["bombs"],
        "full_disk_recovers": TALLY["full_disk"],
        "inputs_changed_by_recover": 0,
        "tracebacks": TALLY["tracebacks"],
    }
    COUNTS.parent.mkdir(parents=True, exist_ok=True)
    COUNTS.write_text(json.dumps(counts, indent=2) + "\n")


# -- cuts --------------------------------------------------------------------------------------------
SHARDS = 4  # each soak in four parts, so that workers side by side share it (the same offsets
# and corruptions in all: a part takes every fourth)


@pytest.mark.slow  # a read at every cut offset: a soak
@pytest.mark.parametrize("shard", range(SHARDS))
def test_a_recording_cut_at_every_byte_reads_partially_or_fails_clearly(
    tiny: Path, work: Path, shard: int
) -> None:
    data = tiny.read_bytes()
    tmp_path = work
    rss = _peak_rss_mb()
    failures: list[str] = []
    seen: Counter[str] = Counter()
    previous = 0
    offsets = range(shard, len(data), SHARDS)
    for n in offsets:
        (tmp_path / "cut.mcap.part").write_bytes(data[:n])
        outcome, messages = _checked(tmp_path / "cut.mcap.part", tmp_path, failures, f"cut at {n}")
        seen[outcome] += 1
        (tmp_path / "cut.mcap").write_bytes(data[:n])  # the same bytes under the finished name
        again, _ = _checked(tmp_path / "cut.mcap", tmp_path, failures, f"cut at {n} (.mcap)", recover=False)
        assert again == outcome
        if n % 97 == 0:
            _cli(tmp_path / "cut.mcap.part", tmp_path, failures, f"cut at {n}")
        assert messages >= previous, f"a longer prefix ({n} bytes) read fewer messages"
        previous = messages
    TALLY["files_cut"] += shard == 0
    TALLY["cut_offsets"] += len(offsets)
    assert not failures, failures[:3]
    assert seen["full"] == 0 and seen["partial"] > 0 and seen["clean_error"] > 0, seen
    assert _peak_rss_mb() - rss < RSS_GROWTH_MB
    _write_counts()


# -- corruptions -------------------------------------------------------------------------------------
def _records_of(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the top-level records of an intact file."""
    found, pos = [], len(rec.MAGIC)
    while pos + 9 <= len(data) - len(rec.MAGIC):
        opcode, length = rec.RECORD_PREFIX.unpack_from(data, pos)
        found.append((pos, opcode, length))
        pos += 9 + length
    return found


BOMB = zstandard.ZstdCompressor(level=19).compress(bytes(30 << 20))  # 30 MiB of zeros in 1 KB
SMALL_BOMB = zstandard.ZstdCompressor(level=19).compress(bytes(4 << 20))


def _bomb_chunk(declared: int, bomb: bytes = BOMB) -> bytes:
    return rec.chunk(0, 0, declared, 0, compression="zstd", data=bomb)


def _corrupt(rng: random.Random, data: bytes, layout: list[tuple[int, int, int]]) -> tuple[str, bytes]:
    out = bytearray(data)
    chunks = [r for r in layout if r[1] == rec.CHUNK]
    kind = rng.choice(
        ["flip", "overwrite", "zero", "length", "field_length", "crc", "bomb", "garbage_tail", "dup"]
    )
    if kind == "flip":
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] ^= rng.randint(1, 255)
    elif kind in ("overwrite", "zero"):
        start = rng.randrange(len(out))
        size = min(rng.randint(1, 256), len(out) - start)
        out[start : start + size] = bytes(size) if kind == "zero" else rng.randbytes(size)
    elif kind == "length":
        pos, _, length = rng.choice(layout)
        value = rng.choice([2**64 - 1, 2**63, length + rng.randint(1, 4096), rng.getrandbits(40), 0])
        struct.pack_into("<Q", out, pos + 1, value)
    elif kind == "field_length":  # a u32 string or map length somewhere
        struct.pack_into("<I", out, rng.randrange(len(out) - 4), rng.choice([2**32 - 1, 2**31, 0xFFFF0]))
    elif kind == "crc":
        pos = rng.choice(chunks)[0]
        struct.pack_into("<I", out, pos + 9 + 24, rng.getrandbits(32) | 1)
    elif kind == "bomb":
        pos, _, length = rng.choice(chunks)
        declared = rng.choice([4 << 20, 2**40, 2**64 - 1, 1000])
        out[pos : pos + 9 + length] = _bomb_chunk(declared, SMALL_BOMB)
    elif kind == "garbage_tail":
        del out[rng.randrange(len(out)) :]
        out += rng.randbytes(rng.randint(1, 512))
    else:
        pos, _, length = rng.choice(layout)
        at = rng.choice(layout)[0]
        out[at:at] = data[pos : pos + 9 + length]
    return kind, bytes(out)


@pytest.mark.slow  # a fuzz of many corruptions: a soak
@pytest.mark.parametrize("shard", range(SHARDS))
def test_random_corruptions_read_partially_or_fail_clearly(small: Path, work: Path, shard: int) -> None:
    data = small.read_bytes()
    tmp_path = work
    layout = _records_of(data)
    rng = random.Random(SEED)  # every part draws all corruptions, in order, and reads its own
    rss = _peak_rss_mb()
    failures: list[str] = []
    for i in range(CORRUPTIONS):
        kind, corrupted = _corrupt(rng, data, layout)
        if i % SHARDS != shard:
            continue
        TALLY[f"kind_{kind}"] += 1
        path = tmp_path / f"corrupt{'.mcap.part' if i % 2 else '.mcap'}"
        path.write_bytes(corrupted)
        _checked(path, tmp_path, failures, f"corruption {i} ({kind})")
        if i % 10 == 0:
            _cli(path, tmp_path, failures, f"corruption {i} ({kind})")
    TALLY["corruptions"] += len(range(shard, CORRUPTIONS, SHARDS))
    assert not failures, failures[:3]
    assert _peak_rss_mb() - rss < RSS_GROWTH_MB
    _write_counts()


def test_a_bad_chunk_crc_is_reported_and_not_rewritten(small: Path, tmp_path: Path) -> None:
    data = bytearray(small.read_bytes())
    chunks = [(length, p) for p, opcode, length in _records_of(bytes(data)) if opcode == rec.CHUNK]
    pos = max(chunks)[1]  # the biggest chunk: it holds messages
    struct.pack_into("<I", data, pos + 9 + 24, 0xDEADBEEF)
    path = tmp_path / "bad_crc.mcap"
    path.write_bytes(bytes(data))
    recording = read_recording(path)
    assert any("CRC mismatch" in p for p in recording.problems)
    result = recover_file(path, tmp_path / "out.mcap")
    assert any("CRC mismatch" in p for p in result.problems)
    assert result.messages < sum(read_recording(small).message_counts.values())  # the chunk was left out
    assert "DEADBEEF".lower() not in (tmp_path / "out.mcap").read_bytes().hex()


# -- bombs, memory ----------------------------------------------------------------------------------
PROBE = textwrap.dedent(
    """
    import resource, subprocess, sys
    run = subprocess.run([sys.executable, "-m", "bridge.cli", *sys.argv[1:]], capture_output=True, text=True)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024
    print(run.returncode, peak)
    sys.stderr.write(run.stderr + run.stdout)
    """
)


@pytest.mark.parametrize("declared", [2**40, 1000, 30 << 20])
def test_a_decompression_bomb_takes_bounded_memory(tmp_path: Path, declared: int) -> None:
    chunks = [_bomb_chunk(declared) for _ in range(8)]
    body = rec.MAGIC + rec.header("ros2", "bomb") + b"".join(chunks)
    path = tmp_path / "bomb.mcap"
    path.write_bytes(body)
    assert path.stat().st_size < 64 * 1024
    for command in (["info", str(path)], ["recover", str(path), "-o", str(tmp_path / "out.mcap"), "--force"]):
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        probe = subprocess.run(
            [sys.executable, "-c", PROBE, *command], check=False, capture_output=True, text=True, env=env
        )
        code, peak_mb = (int(v) for v in probe.stdout.split())
        TALLY["bombs"] += 1
        assert "Traceback" not in probe.stderr, probe.stderr
        assert code == 0 and "skipped" in probe.stderr, probe.stderr
        assert peak_mb < 400, f"{command[0]} of a {path.stat().st_size}-byte bomb took {peak_mb} MB"


# -- recover never destroys its input ---------------------------------------------------------------
FULL_DISK = textwrap.dedent(
    """
    import resource, sys
    from bridge.errors import BridgeError
    from bridge.recording.reader import recover
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))  # writes past 4 KiB fail with EFBIG
    try:
        recover(sys.argv[1], sys.argv[2], overwrite=True)
    except BridgeError as exc:
        print(exc)
        sys.exit(2)
    """
)


def test_recover_on_a_full_disk_leaves_input_and_output_untouched(small: Path, tmp_path: Path) -> None:
    """A full disk is simulated with RLIMIT_FSIZE (EFBIG once a file passes 4 KiB): it needs no root
    and no mount, and the writer sees the same failed write() as with ENOSPC."""
    part = tmp_path / "run.mcap.part"
    part.write_bytes(small.read_bytes()[:-100])
    output = tmp_path / "run.mcap"
    output.write_bytes(b"an older recovered file")
    before = part.read_bytes()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(part), str(output)],
        check=False,
        capture_output=True,
        text=True,
        env=env,
    )
    TALLY["full_disk"] += 1
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert "untouched" in run.stdout and "File too large" in run.stdout, run.stdout
    assert part.read_bytes() == before
    assert output.read_bytes() == b"an older recovered file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap", "run.mcap.part"]  # no temporary left


def test_recover_refuses_to_write_over_its_input(small: Path, tmp_path: Path) -> None:
    part = tmp_path / "run.mcap.part"
    part.write_bytes(small.read_bytes())
    os.link(part, tmp_path / "alias.mcap")
    for output in (part, tmp_path / "alias.mcap"):
        with pytest.raises(BridgeError, match="other than the input"):
            recover_file(part, output, overwrite=True)
    assert part.read_bytes() == small.read_bytes()


@pytest.mark.slow  # writes the counts of the two fuzz tests above, which are slow
def test_counts_are_written() -> None:
    if TALLY["corruptions"] and TALLY["cut_offsets"]:
        _write_counts()
        counts = json.loads(COUNTS.read_text())
        assert counts["tracebacks"] == 0
        # every corruption this process's parts drew was read and counted by its kind: all of
        # them where one process ran every part (under pytest-xdist the parts are spread)
        assert sum(counts["corruption_kinds"].values()) == counts["corruptions"]
        if "PYTEST_XDIST_WORKER" not in os.environ:
            assert counts["corruptions"] == CORRUPTIONS
        assert zlib.crc32(COUNTS.read_bytes())  # written and not empty


# -- the node recorder --------------------------------------------------------------------------------
@pytest.mark.integration
def test_node_recorder_counts_and_skips_frames_it_cannot_place(loopback: Loopback, tmp_path: Path) -> None:
    """Frames whose time or step no recording can hold are skipped and counted; the frames around
    them are recorded exactly (read back by rosbags)."""
    from bridge.net import protocol as proto
    from bridge.recording.node_recorder import NodeRecorder

    path = tmp_path / "node.mcap"
    hostile = [
        (proto.OUTPUTS, 1, 3, 2**63 - 1),
        (proto.OUTPUTS, 1, 4, -(2**63)),
        (proto.ACTION, 1, 2**62, 0),
        (proto.ACTION, 1, 2**63 - 1, 0),
        (proto.OUTPUTS, 1, 5, 2**31 * 10**9),
    ]
    with node_process(example_experiment("cartpole_continuous"), "hostile", loopback):
        recorder = NodeRecorder(loopback.session, "hostile", path, prefix=loopback.prefix, timeout_s=30)
        size = len(recorder.description["output_names"])
        good = [(k, [float(k)] * size) for k in range(1, 4)]
        for k, values in good[:2]:
            recorder.handle("outputs", proto.encode_values(proto.OUTPUTS, 1, k, k * 20_000_000, values))
        for kind, episode, step, sim_ns in hostile:
            n = size if kind == proto.OUTPUTS else len(recorder.description["input_names"])
            recorder.handle("outputs", proto.encode_values(kind, episode, step, sim_ns, [0.0] * n))
        k, values = good[2]
        recorder.handle("outputs", proto.encode_values(proto.OUTPUTS, 1, k, k * 20_000_000, values))
        stats = recorder.stats
        recorder.close()
    assert stats.unplaced == len(hostile) and stats.malformed == 0
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        found = [
            (reader.deserialize(raw, c.msgtype).position.tolist(), log_ns)
            for c, log_ns, raw in reader.messages()
            if c.topic == meta.OUTPUTS
        ]
    assert [v for v, _ in found] == [v for _, v in good]
    assert [t for _, t in found] == [k * 20_000_000 for k, _ in good]  # episode 1 starts at 0
