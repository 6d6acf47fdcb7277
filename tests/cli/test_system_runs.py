"""``fmu-bridge system simulate`` as a user runs it: paths from where the command runs, and a run
that fails keeps the rows of every macro step done before it (and says how many)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.errors import BridgeError
from tests.plant.ssp_semantics import motor_load, write

runner = CliRunner()
_load_plugins()


def test_simulate_takes_a_path_relative_to_where_it_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: `'sys/dahl.ssp' does not exist (looked at sys/sys/dahl.ssp)`."""
    (tmp_path / "sys").mkdir()
    write(tmp_path / "sys" / "dahl.ssp", motor_load())
    monkeypatch.chdir(tmp_path)
    args = ["system", "simulate", "sys/dahl.ssp", "--no-feedthrough", "motor", "--duration", "0.01"]
    result = runner.invoke(app, [*args, "--csv", "out.csv"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, (result.output, result.exception)
    assert len((tmp_path / "out.csv").read_text().splitlines()) == 1 + 11  # the header, t0 and 10 steps


def test_a_failed_run_keeps_its_rows_and_says_how_many(tmp_path: Path) -> None:
    """The motor's speed reaches the load through a factor of 1e308: the load's torque overflows
    and the motor refuses it a few steps in; the CSV holds every macro step done before that."""
    huge = '<ssc:LinearTransformation factor="1e308"/>'
    ssp = write(tmp_path / "overflow.ssp", motor_load(omega=huge))
    out = tmp_path / "out.csv"
    args = ["system", "simulate", str(ssp), "--no-feedthrough", "motor", "--csv", str(out)]
    result = runner.invoke(app, args, env={"COLUMNS": "200"})
    assert isinstance(result.exception, BridgeError), result.output
    with out.open() as f:
        rows = list(csv.DictReader(f))
    done = len(rows) - 1  # the start row is not a step
    message = str(result.exception)
    assert 0 < done < 400 and f"the run stopped after {done} macro steps ({done} of 400 samples" in message
    assert f"{out} holds their {len(rows)} rows" in message
    assert "component 'motor' (dcmotor.fmu) failed" in message and "load_torque=nan" in message
    omega = np.array([float(r["motor.omega"]) for r in rows])
    assert np.all(np.isfinite(omega[:-1])) and omega[1] > 0.0
    times = np.array([float(r["time"]) for r in rows])
    np.testing.assert_allclose(times, np.arange(len(rows)) * 1e-3, rtol=0, atol=1e-12)


def test_an_open_loop_yaml_system_needs_no_reward_section(tmp_path: Path) -> None:
    """Before: `reward: Field required` for a system simulated as it is (no actions)."""
    text = """
model: {step_size: 0.001, episode_duration: 0.005}
system:
  components:
    motor: {fmu: "example:dcmotor", feedthrough: false, parameters: {voltage: 12.0}}
    load: {fmu: "example:gearload"}
  connections: [motor.omega -> load.omega_in, load.torque -> motor.load_torque]
observations: {outputs: [load.omega]}
"""
    path = tmp_path / "open_loop.yaml"
    path.write_text(text)
    out = tmp_path / "out.csv"
    result = runner.invoke(app, ["system", "simulate", str(path), "--csv", str(out)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, (result.output, result.exception)
    omega = [float(r["load.omega"]) for r in csv.DictReader(out.open())]
    assert len(omega) == 6 and omega[-1] > 0.0  # the motor drove the load
    with_actions = (
        text + "actions: {inputs: [load.tau_ext], low: {load.tau_ext: -1}, high: {load.tau_ext: 1}}\n"
    )
    path.write_text(with_actions)
    result = runner.invoke(app, ["system", "simulate", str(path)], env={"COLUMNS": "200"})
    assert "reward" in str(result.exception) and "Field required" in str(result.exception)


def test_a_failed_run_keeps_its_recording(tmp_path: Path) -> None:
    """`fmu-bridge simulate` of a system that fails: the MCAP holds every sample before the
    failure (read back with the mcap package's own reader)."""
    from collections import Counter

    from mcap.reader import make_reader

    write(tmp_path / "overflow.ssp", motor_load(omega='<ssc:LinearTransformation factor="1e308"/>'))
    (tmp_path / "overflow.yaml").write_text(
        "model: {fmu: overflow.ssp, step_size: 0.001, episode_duration: 0.4}\n"
        "system: {components: {motor: {feedthrough: false}}}\n"
        "observations: {outputs: [motor.omega, load.omega]}\n"
    )
    recordings = tmp_path / "recs"
    args = ["simulate", str(tmp_path / "overflow.yaml"), "--episodes", "1", "--recordings", str(recordings)]
    result = runner.invoke(app, args, env={"COLUMNS": "200"})
    assert isinstance(result.exception, BridgeError) and "at step 3 of episode 1" in str(result.exception)
    (path,) = recordings.glob("*.mcap")
    with path.open("rb") as stream:
        topics = Counter(channel.topic for _, channel, _ in make_reader(stream).iter_messages())
    # the reset and the two samples before the one whose outputs were not finite
    assert topics["/outputs"] == 3 and topics["/components/motor/outputs"] == 3 and topics["/actions"] == 2


def test_a_typed_system_that_fails_keeps_the_same_rows_on_either_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Integer and Boolean links (the native master since they are native): b fails its 7th
    doStep; the CSV holds the start and the six macro steps before, the same on both masters."""
    path = tmp_path / "typed.yaml"
    path.write_text(
        "model: {step_size: 0.1, episode_duration: 2.0}\n"
        "system:\n"
        "  components:\n"
        "    a: {fmu: 'example:typed:2.0', start_values: {integer_in: 4, boolean_in: true, enum_in: 3}}\n"
        "    b: {fmu: 'example:typed:2.0', parameters: {fail_at_step: 7}}\n"
        "  connections:\n"
        "    [a.integer_out -> b.integer_in, a.boolean_out -> b.boolean_in, a.enum_out -> b.enum_in]\n"
        "observations: {outputs: [b.integer_out, b.boolean_out, b.enum_out, b.counter]}\n"
    )

    def simulate() -> tuple[list[dict[str, str]], str]:
        out = tmp_path / "out.csv"
        result = runner.invoke(
            app, ["system", "simulate", str(path), "--csv", str(out)], env={"COLUMNS": "200"}
        )
        assert isinstance(result.exception, BridgeError), result.output
        with out.open() as f:
            return list(csv.DictReader(f)), str(result.exception)

    inspected = runner.invoke(app, ["system", "inspect", str(path), "--json"], env={"COLUMNS": "200"})
    assert json.loads(inspected.output)["master"]["runs"] == "native", inspected.output
    native = simulate()
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    assert simulate() == native
    rows, message = native
    assert len(rows) == 7 and "the run stopped after 6 macro steps" in message, message
    assert "fail_at_step reached" in message
    assert [r["b.integer_out"] for r in rows[2:]] == ["4"] * 5 and rows[-1]["b.counter"] == "6"
    assert rows[-1]["b.enum_out"] == "3" and rows[-1]["b.boolean_out"] == "1"
