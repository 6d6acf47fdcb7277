"""``fmu-bridge state save`` / ``state info``, and ``model.reset_policy: {state_file: ...}`` in an
experiment file: paths relative to the file, run folders that keep the state, refusals with exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from bridge.cli.main import _load_plugins, app
from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError, StateFileError
from bridge.experiment.config import load_experiment
from bridge.fmu import Model, state_file
from tests.conftest import example_fmu

runner = CliRunner()
_load_plugins()


def _experiment(path: Path, fmu: str = "example:slow_init:2.0:cs", **model: object) -> Path:
    inputs = "power" if "slow_init" in fmu else "force"
    data = {
        "name": "state-cli",
        "model": {"fmu": fmu, "step_size": 0.05, "episode_duration": 1.0, **model},
        "actions": {"inputs": [inputs], "low": {inputs: -10.0}, "high": {inputs: 10.0}},
        "observations": {"outputs": ["T" if inputs == "power" else "x"]},
        "reward": {"terms": [{"alive": 1.0}]},
    }
    if inputs == "power":
        data["model"]["parameters"] = {"warmup_steps": 0}  # type: ignore[index]
    path.write_text(yaml.safe_dump(data))
    return path


def test_save_until_a_time_then_info(tmp_path: Path) -> None:
    exp = _experiment(tmp_path / "exp.yaml")
    result = runner.invoke(app, ["state", "save", str(exp), "--until", "2", "-o", str(tmp_path / "a.state")])
    assert result.exit_code == 0, result.output
    assert "at t = 2 s" in result.output
    info = json.loads(runner.invoke(app, ["state", "info", str(tmp_path / "a.state"), "--json"]).output)
    assert (info["model_name"], info["time_s"], info["step_index"]) == ("slow_init", 2.0, 40)
    assert info["start_values"] == {"warmup_steps": 0}
    assert "checksum OK" in runner.invoke(app, ["state", "info", str(tmp_path / "a.state")]).output


def test_save_at_steady_state_settles_below_the_tolerance(tmp_path: Path) -> None:
    exp = _experiment(tmp_path / "exp.yaml")
    out = tmp_path / "steady.state"
    result = runner.invoke(
        app, ["state", "save", str(exp), "--steady", "--tol", "1e-8", "-o", str(out), "--json"]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["change"] <= 1e-8
    # the equilibrium of C dT/dt = 50 - (T - Ta) - 0.001 (T - Ta)^3: dT solves dT + 0.001 dT^3 = 50
    with FmuEnv(_experiment(tmp_path / "from.yaml", reset_policy={"state_file": "steady.state"})) as env:
        _, info = env.reset(seed=0)
        dT = info["outputs"][0] - 293.15
        assert dT + 0.001 * dT**3 == pytest.approx(50.0, rel=1e-5)
        assert info["time_s"] == report["time_s"] > 10.0


def test_steady_state_that_is_not_reached_is_an_error(tmp_path: Path) -> None:
    exp = _experiment(tmp_path / "exp.yaml")
    args = [
        "state",
        "save",
        str(exp),
        "--steady",
        "--tol",
        "1e-12",
        "--max-time",
        "3",
        "-o",
        str(tmp_path / "x"),
    ]
    result = runner.invoke(app, args)
    assert result.exit_code != 0 and isinstance(result.exception, ConfigError)
    assert "did not settle by t = 3 s" in str(result.exception)
    assert not (tmp_path / "x").exists()


def test_refusal_exits_2_naming_the_capability_flag(tmp_path: Path) -> None:
    exp = _experiment(tmp_path / "cp.yaml", fmu="example:cartpole:2.0:cs")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "bridge.cli",
            "state",
            "save",
            str(exp),
            "--until",
            "1",
            "-o",
            str(tmp_path / "c"),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
        timeout=120,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    assert "canSerializeFMUstate=false" in result.stderr and "Traceback" not in result.stderr


def test_state_file_path_is_relative_to_the_experiment_and_must_exist(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    exp = _experiment(tmp_path / "sub" / "exp.yaml")
    assert (
        runner.invoke(
            app, ["state", "save", str(exp), "--until", "1", "-o", str(tmp_path / "sub" / "s.state")]
        ).exit_code
        == 0
    )
    with FmuEnv(_experiment(tmp_path / "sub" / "use.yaml", reset_policy={"state_file": "s.state"})) as env:
        assert env.reset(seed=0)[1]["time_s"] == 1.0
    missing = _experiment(tmp_path / "missing.yaml", reset_policy={"state_file": "s.state"})
    with pytest.raises(ConfigError, match=r"reset_policy.state_file: 's.state' does not exist"):
        FmuEnv(missing)


def test_run_folder_keeps_the_state_file(tmp_path: Path) -> None:
    from agents.train import write_run_experiment

    exp = _experiment(tmp_path / "exp.yaml")
    runner.invoke(app, ["state", "save", str(exp), "--until", "1", "-o", str(tmp_path / "s.state")])
    use = _experiment(tmp_path / "use.yaml", reset_policy={"state_file": "s.state"})
    for mode, expected in (("absolute", str((tmp_path / "s.state").resolve())), ("copy", "s.state")):
        run = tmp_path / mode
        run.mkdir()
        written = yaml.safe_load(write_run_experiment(use, run, fmu=mode).read_text())
        assert written["model"]["reset_policy"]["state_file"] == expected
        with FmuEnv(run / "experiment.yaml") as env:
            assert env.reset(seed=0)[1]["time_s"] == 1.0
    assert (
        state_file.read(tmp_path / "copy" / "s.state").payload
        == state_file.read(tmp_path / "s.state").payload
    )


def test_randomised_start_values_with_a_state_file_are_refused(tmp_path: Path) -> None:
    exp = _experiment(tmp_path / "exp.yaml")
    runner.invoke(app, ["state", "save", str(exp), "--until", "1", "-o", str(tmp_path / "s.state")])
    data = yaml.safe_load(
        _experiment(tmp_path / "r.yaml", reset_policy={"state_file": "s.state"}).read_text()
    )
    data["randomization"] = {"parameters": {"base_power": {"uniform": [40.0, 60.0]}}}
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(data))
    with (
        FmuEnv(load_experiment(tmp_path / "r.yaml")) as env,
        pytest.raises(StateFileError, match="state file fixes every"),
    ):
        env.reset(seed=0)


def test_batch_env_from_a_state_file_equals_the_single_env(tmp_path: Path) -> None:
    """The batch plant's instances (stepped natively together) start from the state as FmuEnv does."""
    import numpy as np

    from bridge.env.batch import BatchEnv

    exp = _experiment(tmp_path / "exp.yaml")
    runner.invoke(app, ["state", "save", str(exp), "--until", "1.5", "-o", str(tmp_path / "s.state")])
    use = _experiment(tmp_path / "use.yaml", reset_policy={"state_file": "s.state"})
    actions = np.array([[0.5], [-0.25]], dtype=np.float32)
    batch = BatchEnv(use, 2)
    try:
        rows = [batch.reset_all([1, 2])[0].copy()]
        rows += [batch.step(actions)[0].copy() for _ in range(6)]
    finally:
        batch.close()
    for i in range(2):
        with FmuEnv(use) as env:
            single = [env.reset(seed=i + 1)[0]] + [env.step(actions[i])[0] for _ in range(6)]
        np.testing.assert_array_equal(np.array(rows)[:, i, :], np.array(single))


ME_SLOPES = "1 state derivatives (model exchange)"


@pytest.mark.parametrize(
    ("model", "version", "interface", "watched"),
    [
        ("slow_init", "2.0", "me", ME_SLOPES),
        ("slow_init", "3.0", "me", ME_SLOPES),
        ("slow_init_late", "2.0", "cs", "der(T)"),  # co-simulation that lists <Derivatives>
        ("slow_init", "3.0", "cs", ""),  # co-simulation without them: the outputs alone
    ],
)
def test_steady_watches_the_state_derivatives_the_fmu_offers(
    model: str, version: str, interface: str, watched: str, tmp_path: Path
) -> None:
    """Model exchange: every state's derivative (getDerivatives / getContinuousStateDerivatives);
    co-simulation: the <Derivatives> variables read by value reference, where listed. The saved
    state is the closed-form equilibrium, and its derivative is below the tolerance over a window."""
    exp = _experiment(tmp_path / "exp.yaml", fmu=f"example:{model}:{version}:{interface}")
    out = tmp_path / "steady.state"
    args = ["state", "save", str(exp), "--steady", "--tol", "1e-9", "--window", "0.5", "-o", str(out)]
    result = runner.invoke(app, [*args, "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["derivatives"] == watched
    with Model(example_fmu(model, version, interface), step_size_s=0.05) as m:
        m.start_from(state_file.read(out))
        m.reset({"warmup_steps": 0})
        T = m.get(["T"])["T"]
        offered = m.derivatives()[0] if interface == "me" else m.get([watched])[watched] if watched else None
    dT = T - 293.15
    slope = (50.0 - dT - 0.001 * dT**3) / 20.0  # C dT/dt at the saved state, closed form
    assert dT + 0.001 * dT**3 == pytest.approx(50.0, rel=1e-6)
    assert abs(slope) * 0.5 <= 1e-9 * T
    if offered is not None:
        assert offered == pytest.approx(slope, abs=1e-12)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--until", "-1"], "--until -1 s is before the FMU's start time 0 s"),
        ([], "say when to save: --until T (simulation time, s) or --steady"),
        (["--until", "1", "--steady"], "not both"),
    ],
)
def test_state_save_refuses_a_time_before_the_start_and_says_what_is_missing(
    tmp_path: Path, args: list[str], said: str
) -> None:
    """Before: ``--until -1`` saved the state at t = 0, and no option at all was answered with "not both"."""
    exp = _experiment(tmp_path / "e.yaml")
    result = runner.invoke(app, ["state", "save", str(exp), *args, "-o", str(tmp_path / "w.state")])
    assert isinstance(result.exception, ConfigError), result.output
    assert said in str(result.exception)
    assert not (tmp_path / "w.state").exists()
