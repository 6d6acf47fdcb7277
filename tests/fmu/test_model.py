"""bridge.fmu.Model on our own example FMUs, checked against FMPy's simulate_fmu and physics."""

from __future__ import annotations

import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu

from bridge.errors import ConfigError, FmuLoadError, StepError, VariableError
from bridge.fmu import Model, archive
from bridge.models import example_fmu

CARTPOLE_OUT = ["x", "x_dot", "theta", "theta_dot"]


def run_model(model: Model, force: float, samples: int, n: int = 1) -> np.ndarray:
    inputs = model.signals(["force"], writable=True)
    outputs = model.signals(CARTPOLE_OUT)
    rows = [outputs.read()]
    for _ in range(samples):
        inputs.write([force])
        model.advance(n)
        rows.append(outputs.read())
    return np.array(rows)


@pytest.mark.parametrize("version", ["1.0", "2.0", "3.0"])
def test_cartpole_cs_equals_fmpy_simulate_fmu(version: str) -> None:
    path = example_fmu("cartpole", version, "cs")
    start = {"theta0": 0.05, "m_pole": 0.2}
    with Model(path, step_size_s=0.02) as model:
        model.initialize(start)
        ours = run_model(model, 3.0, 50)
    signal = np.array([(0.0, 3.0), (1.0, 3.0)], dtype=[("time", np.float64), ("force", np.float64)])
    ref = simulate_fmu(
        str(path),
        fmi_type="CoSimulation",
        start_values=start,
        input=signal,
        stop_time=1.0,
        output_interval=0.02,
        step_size=0.02,
        output=CARTPOLE_OUT,
    )
    expected = np.column_stack([ref[name] for name in CARTPOLE_OUT])
    np.testing.assert_allclose(ours, expected[: len(ours)], rtol=0, atol=1e-12)
    assert abs(ours[-1, 2] - ours[0, 2]) > 0.1  # the pole really moved


def test_fmi_versions_and_interfaces_agree() -> None:
    trajectories = {}
    for version, interface in [("1.0", "cs"), ("2.0", "cs"), ("3.0", "cs"), ("2.0", "me"), ("3.0", "me")]:
        tolerance = 1e-9 if interface == "me" else None  # CVode's default 1e-6 drifts ~1e-4 here
        with Model(
            example_fmu("cartpole", version, interface), step_size_s=0.02, tolerance=tolerance
        ) as model:
            model.initialize({"theta0": 0.1})
            trajectories[(version, interface)] = run_model(model, -2.0, 40)
    cs = trajectories[("2.0", "cs")]
    np.testing.assert_array_equal(trajectories[("1.0", "cs")], cs)
    np.testing.assert_array_equal(trajectories[("3.0", "cs")], cs)
    for key in [("2.0", "me"), ("3.0", "me")]:  # CVode vs RK4 at 1 ms: same physics
        np.testing.assert_allclose(trajectories[key], cs, atol=1e-6)


def test_n_fmu_steps_per_sample_equals_single_steps(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu, step_size_s=0.01) as a, Model(cartpole_fmu, step_size_s=0.01) as b:
        a.initialize({"theta0": 0.05})
        b.initialize({"theta0": 0.05})
        every_other = run_model(a, 1.0, 60)[::2]
        paired = run_model(b, 1.0, 30, n=2)
        np.testing.assert_array_equal(every_other, paired)
        assert b.step_index == 60 and b.time_s == pytest.approx(0.6, abs=1e-15)


def test_time_is_integer_indexed_not_accumulated(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu, step_size_s=0.1, start_time_s=1.0) as model:
        model.initialize()
        for _ in range(1000):
            model.advance(1)
        assert model.time_s == 1.0 + 1000 * 0.1  # exactly, no float drift


def test_dcmotor_step_response_matches_analytic(dcmotor_fmu: Path) -> None:
    from scipy.linalg import expm

    r, inductance, k, j, b = 1.0, 0.0025, 0.1, 0.01, 1e-4
    a_mat = np.array([[-r / inductance, -k / inductance], [k / j, -b / j]])
    b_mat = np.array([1 / inductance, 0.0])
    h, volts = 0.01, 12.0
    phi = expm(a_mat * h)
    gamma = np.linalg.solve(a_mat, (phi - np.eye(2)) @ b_mat)
    state = np.zeros(2)
    with Model(dcmotor_fmu, step_size_s=h) as model:
        model.initialize()
        inputs = model.signals(["voltage"], writable=True)
        outputs = model.signals(["current", "omega"])
        for _ in range(200):
            inputs.write([volts])
            model.advance(1)
            state = phi @ state + gamma * volts
            np.testing.assert_allclose(outputs.read(), state, rtol=1e-6, atol=1e-6)


def test_typed_variables_round_trip_with_their_own_types(typed_fmu3: Path) -> None:
    values = {
        "real_in": 1.25,
        "float32_in": 0.5,
        "int8_in": -128,
        "uint8_in": 255,
        "int16_in": -32768,
        "uint16_in": 65535,
        "integer_in": -2147483648,
        "uint32_in": 4294967295,
        "int64_in": -(2**62) - 3,
        "uint64_in": 2**63 + 5,
        "boolean_in": True,
        "string_in": "hello fmi",
        "enum_in": 3,
    }
    with Model(typed_fmu3, step_size_s=0.1) as model:
        model.initialize()
        model.set(values)
        model.advance(1)
        out = model.get([name.replace("_in", "_out") for name in values])
    for name, value in values.items():
        got = out[name.replace("_in", "_out")]
        assert got == value and type(got) is type(value), name  # exact, no float round trip


def test_typed_fmi2_signal_group_reads_integers_and_booleans_exactly(typed_fmu2: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.1) as model:
        model.initialize()
        inputs = model.signals(["real_in", "integer_in", "boolean_in", "enum_in"], writable=True)
        outputs = model.signals(["real_out", "integer_out", "boolean_out", "enum_out", "counter"])
        inputs.write([2.5, 123456789, 1, 2])
        model.advance(1)
        np.testing.assert_array_equal(outputs.read(), [2.5, 123456789, 1, 2, 1])
        with pytest.raises(VariableError, match="whole numbers"):
            inputs.write([2.5, 1.5, 1, 2])
        with pytest.raises(VariableError, match="0 or 1"):
            inputs.write([2.5, 1, 2, 2])


def test_tunable_parameter_between_steps_and_fixed_one_refused(typed_fmu2: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.1) as model:
        model.initialize({"gain": 2.0})
        model.set({"real_in": 1.5})
        model.advance(1)
        assert model.get(["real_scaled"])["real_scaled"] == pytest.approx(3.0)
        model.set({"gain": 4.0})
        model.advance(1)
        assert model.get(["real_scaled"])["real_scaled"] == pytest.approx(6.0)
        with pytest.raises(VariableError, match="only be set at initialisation"):
            model.set({"real_param": 1.0})


def test_fmu_requested_termination_stops_stepping(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu, step_size_s=0.02) as model:
        model.initialize({"track_limit": 0.05})
        inputs = model.signals(["force"], writable=True)
        terminated = False
        for _ in range(200):
            inputs.write([10.0])
            if model.advance(1):
                terminated = True
                break
        assert terminated and model.terminated
        assert abs(model.get(["x"])["x"]) > 0.05
        with pytest.raises(StepError, match="requested termination"):
            model.advance(1)
        model.reset({"track_limit": 0.05})
        assert not model.terminated and model.step_index == 0


def test_fmu_error_during_step_carries_log_step_and_time(typed_fmu2: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.5) as model:
        model.initialize({"fail_at_step": 3})
        model.advance(2)
        with pytest.raises(StepError) as caught:
            model.advance(5)
        error = caught.value
        assert "fail_at_step reached" in str(error)
        assert (error.step, error.time_s) == (2, 1.0)
        with pytest.raises(StepError, match="previous step failed"):
            model.advance(1)
        model.reset({"fail_at_step": -1})
        model.advance(5)
        assert model.get(["counter"])["counter"] == 5


def test_step_size_the_fmu_rejects(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu, step_size_s=2.0) as model:
        model.initialize()
        with pytest.raises(StepError, match=r"Error at step 0 .*h=2 s") as caught:
            model.advance(1)
        assert any("step" in line for line in caught.value.log)


@pytest.mark.parametrize("policy", ["reset", "restore", "reinstantiate", "auto"])
def test_every_reset_policy_replays_the_trajectory(cartpole_fmu: Path, policy: str) -> None:
    with Model(cartpole_fmu, step_size_s=0.02, reset_policy=policy) as model:  # type: ignore[arg-type]
        model.initialize({"theta0": 0.03})
        first = run_model(model, 1.0, 30)
        for _ in range(3):
            model.reset({"theta0": 0.03})
            np.testing.assert_array_equal(run_model(model, 1.0, 30), first)
        model.reset({"theta0": -0.03})
        other = run_model(model, 1.0, 30)
        assert other[0, 2] == pytest.approx(-0.03)


def test_auto_policy_snapshots_recurring_values_only(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu, step_size_s=0.02) as model:
        model.initialize({"theta0": 0.01})
        for i in range(20):
            model.reset({"theta0": 0.01 * (i % 2)})  # two recurring value sets
            model.advance(2)  # auto keeps a snapshot taken after an fmi reset once its episode ran
        assert sum(s is not None for s in model._snapshots.by_key.values()) == 2
        for i in range(20):
            model.reset({"theta0": 0.5 + i})  # never seen twice: no snapshots taken
        assert sum(s is not None for s in model._snapshots.by_key.values()) <= 2


def test_reinstantiation_never_re_extracts(cartpole_fmu: Path, tmp_path: Path) -> None:
    private = tmp_path / "cartpole.fmu"  # a file no other open instance shares
    private.write_bytes(cartpole_fmu.read_bytes())
    cartpole_fmu = private
    before = archive.extraction_count()
    with Model(cartpole_fmu, step_size_s=0.02, reset_policy="reinstantiate") as model:
        model.initialize()
        directory = model._unzip
        mtime = directory.stat().st_mtime_ns
        with Model(cartpole_fmu, step_size_s=0.02) as second:
            assert second._unzip == directory  # instances share the extraction
        for _ in range(20):
            model.reset()
        assert archive.extraction_count() == before + 1
        assert directory.stat().st_mtime_ns == mtime
    assert archive.extraction_count() == before
    assert not directory.exists()


@pytest.mark.slow
@pytest.mark.parametrize("policy", ["reset", "restore", "reinstantiate"])
def test_no_memory_growth_over_10000_resets(cartpole_fmu: Path, policy: str) -> None:
    psutil = pytest.importorskip("psutil")
    process = psutil.Process()
    with Model(cartpole_fmu, step_size_s=0.02, reset_policy=policy) as model:  # type: ignore[arg-type]
        model.initialize({"theta0": 0.02})
        for _ in range(1000):  # warm up allocator pools
            model.reset({"theta0": 0.02})
            model.advance(1)
        rss = process.memory_info().rss
        for _ in range(10_000):
            model.reset({"theta0": 0.02})
            model.advance(1)
        growth = process.memory_info().rss - rss
    assert growth < 2 * 1024 * 1024, f"RSS grew by {growth / 1024:.0f} KiB over 10,000 resets ({policy})"


def test_not_a_zip(tmp_path: Path) -> None:
    bogus = tmp_path / "model.fmu"
    bogus.write_text("this is not an archive")
    with pytest.raises(FmuLoadError, match="not a zip"):
        Model(bogus)


def test_zip_without_model_description(tmp_path: Path) -> None:
    bogus = tmp_path / "model.fmu"
    with zipfile.ZipFile(bogus, "w") as z:
        z.writestr("readme.txt", "hello")
    with pytest.raises(FmuLoadError, match=r"no modelDescription\.xml"):
        Model(bogus)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FmuLoadError, match="not found"):
        Model(tmp_path / "nope.fmu")


def test_no_binary_for_this_platform(cartpole_fmu: Path, tmp_path: Path) -> None:
    stripped = tmp_path / "windows_only.fmu"
    with zipfile.ZipFile(cartpole_fmu) as src, zipfile.ZipFile(stripped, "w") as dst:
        for item in src.infolist():
            if item.filename.startswith("binaries/linux64"):
                dst.writestr(item.filename.replace("linux64", "win64").replace(".so", ".dll"), b"MZ")
            else:
                dst.writestr(item, src.read(item))
    with pytest.raises(FmuLoadError, match=r"no binary for this platform \(linux64\): it ships win64"):
        Model(stripped)


def test_unknown_variable_suggests_close_names(cartpole_fmu: Path) -> None:
    with (
        Model(cartpole_fmu) as model,
        pytest.raises(VariableError, match=r"'thetta'.*did you mean \['theta'"),
    ):
        model.signals(["thetta"])


def test_setting_constant_or_calculated_variables_is_refused(typed_fmu2: Path, cartpole_fmu: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.1) as model:
        with pytest.raises(VariableError, match=r"'double_gain'.*cannot be set.*calculatedParameter"):
            model.initialize({"double_gain": 3.0})
        with pytest.raises(VariableError, match=r"'pi'.*constant"):
            model.initialize({"pi": 3.0})
    with Model(cartpole_fmu) as model:
        model.initialize()
        with pytest.raises(VariableError, match=r"'x'.*cannot be set.*output"):
            model.set({"x": 1.0})


def test_nan_input_is_refused_before_reaching_the_fmu(cartpole_fmu: Path) -> None:
    with Model(cartpole_fmu) as model:
        model.initialize()
        inputs = model.signals(["force"], writable=True)
        with pytest.raises(VariableError, match=r"force=nan at step 0 .*finite"):
            inputs.write([math.nan])
        with pytest.raises(VariableError, match="finite"):
            model.set({"force": math.inf})
        model.advance(1)  # the model is untouched and still steps


def test_missing_step_size_is_a_config_error(tmp_path: Path, cartpole_fmu: Path) -> None:
    with pytest.raises(ConfigError, match="positive finite"):
        Model(cartpole_fmu, step_size_s=0.0)


def test_fmu_log_is_captured_per_instance(typed_fmu2: Path) -> None:
    with Model(typed_fmu2, step_size_s=0.5) as a, Model(typed_fmu2, step_size_s=0.5) as b:
        a.initialize({"fail_at_step": 1})
        b.initialize()
        with pytest.raises(StepError):
            a.advance(3)
        b.advance(3)
        assert any("fail_at_step" in line for line in a.log)
        assert not any("fail_at_step" in line for line in b.log)


def test_close_is_idempotent_and_frees_the_extraction(cartpole_fmu: Path) -> None:
    model = Model(cartpole_fmu)
    model.initialize()
    model.close()
    model.close()
    with pytest.raises(StepError):
        model.advance(1)
