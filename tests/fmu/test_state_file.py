"""FMU state files: a state saved to a file and read back starts episodes that equal, bit for
bit, those started from the in-memory snapshot; hostile or foreign files are refused before the FMU
sees a byte; FMUs without canSerializeFMUstate are refused by name."""

from __future__ import annotations

import dataclasses
import json
import struct
from pathlib import Path

import numpy as np
import pytest

from bridge.errors import FmuError, StateFileError
from bridge.fmu import Model, serial, state_file
from tests.conftest import example_fmu

VARIANTS = [("2.0", "cs"), ("2.0", "me"), ("3.0", "cs"), ("3.0", "me")]
FAST = {"warmup_steps": 0}  # initialise at ambient: the state moves, so a wrong restore shows


def _powers(n: int) -> list[float]:
    return [20.0 * np.sin(0.3 * k) + 3.0 for k in range(n)]


def _episode(model: Model, powers: list[float]) -> np.ndarray:
    out = []
    for p in powers:
        model.set({"power": p})
        model.advance(2)
        out.append([model.time_s, model.get(["T"])["T"]])
    return np.array(out)


def _saved(fmu: Path, steps: int = 37) -> tuple[np.ndarray, np.ndarray, state_file.StateFile]:
    """(the episode after a restore of the in-memory snapshot, the original run's continuation, the file)."""
    with Model(fmu, step_size_s=0.05) as m:
        m.initialize(FAST)
        _episode(m, _powers(steps))
        snapshot = m.save_state()
        saved = m.state_file(snapshot)
        continued = _episode(m, _powers(25))
        m.restore_state(snapshot)
        restored = _episode(m, _powers(25))
        m.free_state(snapshot)
    return restored, continued, saved


@pytest.mark.parametrize(("version", "interface"), VARIANTS)
def test_episode_from_state_file_equals_in_memory_snapshot_bit_for_bit(
    version: str, interface: str, tmp_path: Path
) -> None:
    fmu = example_fmu("slow_init", version, interface)
    restored, continued, saved = _saved(fmu)
    state_file.write(tmp_path / "s.state", saved)
    with Model(fmu, step_size_s=0.05) as m:
        m.start_from(state_file.read(tmp_path / "s.state"))
        episodes = []
        for _ in range(3):  # every reset returns to the saved state
            m.reset(FAST)
            assert m.time_s == saved.header.time_s
            episodes.append(_episode(m, _powers(25)))
    for episode in episodes:
        assert np.array_equal(episode, restored)
    assert np.array_equal(restored, continued)
    assert restored[-1, 1] != restored[0, 1]  # the state moves: equality is not trivial


def test_state_file_reset_skips_initialisation() -> None:
    """The state is set straight after instantiation: the (slow) initialisation never runs."""
    fmu = example_fmu("slow_init", "2.0", "cs")
    with Model(fmu, step_size_s=0.05) as m:
        m.initialize({"warmup_steps": 2000})
        m.set({"power": 40.0})
        m.advance(20)
        saved = m.state_file()
        values = m.get(["T_init", "T"])
    assert values["T"] > values["T_init"] > 300.0
    with Model(fmu, step_size_s=0.05) as m:
        m.start_from(saved)
        m.reset({"warmup_steps": 2000})
        assert m.get(["T_init", "T"]) == values
        assert m.init_values == {}  # Model._initialize (enter/exit initialisation mode) never ran


def test_other_step_size_starts_at_the_saved_time(tmp_path: Path) -> None:
    fmu = example_fmu("slow_init", "2.0", "cs")
    with Model(fmu, step_size_s=0.05) as m:
        m.initialize(FAST)
        m.advance(7)
        saved = m.state_file()
    with Model(fmu, step_size_s=0.1) as m:
        m.start_from(saved)
        m.reset()
        assert (m.step_index, m.time_s) == (0, saved.header.time_s)
        m.advance(1)
        assert m.time_s == pytest.approx(0.45)


def test_fmu_without_the_flag_is_refused_by_name(cartpole_fmu: Path, cartpole_fmu3: Path) -> None:
    flags = {cartpole_fmu: "canSerializeFMUstate=false", cartpole_fmu3: "canSerializeFMUState=false"}
    for fmu, flag in flags.items():
        with Model(fmu) as m:
            assert not m.can_serialize
            m.initialize()
            with pytest.raises(StateFileError, match=flag):
                m.state_file()
            assert m.serialize_refusal is not None and "canGetAndSetFMU" in m.serialize_refusal


def test_state_of_another_fmu_is_refused() -> None:
    _, _, saved = _saved(example_fmu("slow_init", "2.0", "cs"), steps=3)
    for version, interface in (("3.0", "cs"), ("2.0", "me")):
        fmu = example_fmu("slow_init", version, interface)
        with Model(fmu, step_size_s=0.05) as m, pytest.raises(StateFileError, match="saved by another FMU"):
            m.start_from(saved, "s.state")


def test_state_with_other_start_values_is_refused() -> None:
    fmu = example_fmu("slow_init", "2.0", "cs")
    _, _, saved = _saved(fmu, steps=3)
    with Model(fmu, step_size_s=0.05) as m:
        m.start_from(saved, "s.state")
        with pytest.raises(StateFileError, match=r"base_power=60\.0 \(saved: 'not set'\)"):
            m.reset({"base_power": 60.0})


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    _, _, saved = _saved(example_fmu("slow_init", "3.0", "cs"), steps=3)
    path = tmp_path_factory.mktemp("state") / "good.state"
    state_file.write(path, saved)
    return path


def test_cut_file_is_refused(good: Path, tmp_path: Path) -> None:
    data = good.read_bytes()
    for keep in (len(data) - 1, 40, 12, 3, 0):
        cut = tmp_path / f"cut{keep}.state"
        cut.write_bytes(data[:keep])
        with pytest.raises(StateFileError, match=r"cut|not an fmu-bridge state file"):
            state_file.read(cut)


def test_padded_or_corrupted_file_is_refused(good: Path, tmp_path: Path) -> None:
    data = good.read_bytes()
    padded = tmp_path / "padded.state"
    padded.write_bytes(data + b"\0")
    with pytest.raises(StateFileError, match="longer than its header says"):
        state_file.read(padded)
    flipped = bytearray(data)
    flipped[-5] ^= 0x01
    with pytest.raises(StateFileError, match="corrupted"):
        state_file.decode(bytes(flipped), source="flipped")


def test_huge_header_and_huge_state_are_refused_before_reading(good: Path, tmp_path: Path) -> None:
    huge = tmp_path / "huge_header.state"
    huge.write_bytes(struct.pack("<8sHI", b"FMUSTATE", 1, 2**32 - 1) + b"{}")
    with pytest.raises(StateFileError, match="header claims 4294967295 bytes"):
        state_file.read(huge)
    header = state_file.read_header(good)
    claims = dataclasses.replace(header, size=2**40)
    big = tmp_path / "huge_state.state"
    big.write_bytes(state_file.encode(claims, b""))
    with pytest.raises(StateFileError, match=r"1099511627776 bytes, more than the \d+ allowed"):
        state_file.read(big)
    with pytest.raises(StateFileError, match="more than the 10 allowed"):
        state_file.read(good, max_bytes=10)


def test_invalid_headers_are_refused(good: Path, tmp_path: Path) -> None:
    def written(text: bytes, version: int = 1) -> Path:
        path = tmp_path / "h.state"
        path.write_bytes(struct.pack("<8sHI", b"FMUSTATE", version, len(text)) + text)
        return path

    for text, reason in (
        (b"\xff\xfe", "header is invalid"),
        (b"[1, 2]", "a JSON object was expected"),
        (b'{"size": 0}', "header is invalid"),
    ):
        with pytest.raises(StateFileError, match=reason):
            state_file.read(written(text))
    fields = json.loads(json.dumps(dataclasses.asdict(state_file.read_header(good))))
    fields["step_index"] = "3"
    with pytest.raises(StateFileError, match="step_index has the wrong type"):
        state_file.read(written(json.dumps(fields).encode()))
    with pytest.raises(StateFileError, match="format version 9 is not supported"):
        state_file.read(written(b"{}", version=9))
    with pytest.raises(StateFileError, match="not an fmu-bridge state file"):
        state_file.read(example_fmu("slow_init", "3.0", "cs"))


def test_fmu_refuses_bytes_that_are_not_its_state(good: Path) -> None:
    """Bytes with a valid header and checksum that the FMU's own deserialiser refuses."""
    saved = state_file.read(good)
    payload = saved.payload[:-8]
    with Model(example_fmu("slow_init", "3.0", "cs"), step_size_s=0.05) as m:
        m.start_from(state_file.seal(saved.header, payload))
        with pytest.raises(FmuError, match="not a serialised state of slow_init"):
            m.reset()


def test_mutated_files_are_refused_or_read_unchanged(good: Path) -> None:
    """Random byte changes, cuts and insertions anywhere: every outcome is a StateFileError, or (a
    change the format does not cover, such as JSON whitespace) the same header and state."""
    data = good.read_bytes()
    original = state_file.decode(data)
    rng = np.random.default_rng(27)
    refused = 0
    for _ in range(2000):
        mutated = bytearray(data)
        at = int(rng.integers(0, len(data)))
        kind = rng.integers(0, 3)
        if kind == 0:
            mutated[at] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            del mutated[at:]
        else:
            mutated[at:at] = bytes(rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8))
        try:
            decoded = state_file.decode(bytes(mutated))
        except StateFileError:
            refused += 1
            continue
        assert decoded == original
    assert refused > 1900


@pytest.mark.parametrize(("version", "interface"), [("2.0", "cs"), ("3.0", "me")])
def test_fmu_that_takes_a_state_only_once_initialised_is_initialised_first(
    version: str, interface: str
) -> None:
    """slow_init_late refuses to deserialise or set a state before initialisation: the first reset
    initialises it with the saving run's start values, then sets the state; the episodes still
    equal the in-memory snapshot's bit for bit."""
    fmu = example_fmu("slow_init_late", version, interface)
    restored, continued, saved = _saved(fmu)
    with Model(fmu, step_size_s=0.05) as m, pytest.raises(FmuError, match=r"(?i)deserializeFMUstate failed"):
        serial.deserialize(m.backend, saved.payload)  # the refusal the fallback exists for
    with Model(fmu, step_size_s=0.05) as m:
        m.start_from(saved)
        episodes = []
        for _ in range(3):
            m.reset(FAST)
            assert m.time_s == saved.header.time_s
            episodes.append(_episode(m, _powers(25)))
        assert m.init_values == FAST  # initialised once, with the saved start values
    for episode in episodes:
        assert np.array_equal(episode, restored)
    assert np.array_equal(restored, continued) and restored[-1, 1] != restored[0, 1]


def test_with_a_state_key_only_files_signed_with_it_are_loaded(
    good: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A resealed file passes the checksum (anyone can compute one); with the user's secret set,
    a file must carry the MAC under that secret, or it is refused before the FMU sees it."""
    unsigned = state_file.read(good)
    monkeypatch.setenv(state_file.KEY_ENV, "alice's secret, 32 bytes long!!")
    with pytest.raises(StateFileError, match="is not signed, and FMU_BRIDGE_STATE_KEY is set"):
        state_file.read(good)
    signed = state_file.seal(unsigned.header, unsigned.payload)
    state_file.write(tmp_path / "signed.state", signed)
    assert state_file.read(tmp_path / "signed.state").payload == unsigned.payload
    crafted = dataclasses.replace(signed.header, time_s=signed.header.time_s + 1.0)
    forged = dataclasses.replace(  # a crafted file resealed, with a MAC copied from a signed one
        state_file.seal(crafted, signed.payload).header, mac=signed.header.mac
    )
    (tmp_path / "forged.state").write_bytes(state_file.encode(forged, signed.payload))
    with pytest.raises(StateFileError, match="is signed with another key"):
        state_file.read(tmp_path / "forged.state")
    monkeypatch.setenv(state_file.KEY_ENV, "mallory's secret, also 32 bytes!")
    with pytest.raises(StateFileError, match="is signed with another key"):
        state_file.read(tmp_path / "signed.state")
    monkeypatch.setenv(state_file.KEY_ENV, "short")
    with pytest.raises(StateFileError, match="at least 16"):
        state_file.read(tmp_path / "signed.state")
    monkeypatch.delenv(state_file.KEY_ENV)
    key_file = tmp_path / "key"
    key_file.write_text("alice's secret, 32 bytes long!!\n")
    monkeypatch.setenv(state_file.KEY_FILE_ENV, str(key_file))
    assert state_file.read(tmp_path / "signed.state").header.mac == signed.header.mac
    monkeypatch.delenv(state_file.KEY_FILE_ENV)
    assert state_file.read(good).header.mac == ""  # without a secret: files load as before


@pytest.mark.parametrize("version", ["2.0", "3.0"])
@pytest.mark.parametrize("change", [-8, 8])
def test_a_state_of_the_wrong_size_is_named_as_such(good: Path, version: str, change: int) -> None:
    """A resealed state of the wrong size is reported as a state the FMU refused, with its size,
    not as whatever FMI call failed after the refusal."""
    fmu = example_fmu("slow_init", version, "cs")
    with Model(fmu, step_size_s=0.05) as m:
        m.initialize(FAST)
        snapshot = m.save_state()
        saved = m.state_file(snapshot)
        m.free_state(snapshot)
    payload = saved.payload[:change] if change < 0 else saved.payload + bytes(change)
    with Model(fmu, step_size_s=0.05) as m:
        m.start_from(state_file.seal(saved.header, payload), "crafted.state")
        with pytest.raises(FmuError) as caught:
            m.reset()
    message = str(caught.value)
    assert f"slow_init refused the state it was given: its {len(payload)} bytes" in message, message
    assert "[crafted.state]" in message and "not a serialised state of slow_init" in message
