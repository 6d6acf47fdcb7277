"""bridge.fmu on FMUs the project did not write: pythonfmu (FMI 2.0), pythonfmu3 (FMI 3.0), Dymola."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu

from bridge.errors import FmuLoadError, VariableError
from bridge.fmu import Model, read_model_info

LOSS, GAIN, STEP = 0.1, 0.01, 1.0


def heater_reference(room0: float, ambient: float, power: float, factor: float, k: int) -> float:
    """Closed-form room temperature after k steps of constant heating."""
    target = ambient + GAIN * power * factor / LOSS
    return target + (room0 - target) * math.exp(-LOSS * STEP * k)


@pytest.mark.parametrize("fixture", ["pythonfmu_heater2", "pythonfmu_heater3"])
def test_exported_heater_steps_typed_inputs_and_matches_closed_form(
    fixture: str, request: pytest.FixtureRequest
) -> None:
    path: Path = request.getfixturevalue(fixture)
    with Model(path, step_size_s=STEP) as model:
        model.initialize({"ambient": 15.0, "label": "kitchen", "mode": 3})
        inputs = model.signals(["power", "enabled", "mode"], writable=True)
        outputs = model.signals(["room", "steps", "heating"])
        for k in range(1, 6):
            inputs.write([100.0, 1, 3])
            model.advance(1)
            room, steps, heating = outputs.read()
            assert room == pytest.approx(heater_reference(20.0, 15.0, 100.0, 1.0, k), abs=1e-12)
            assert (steps, heating) == (k, 1.0)
        inputs.write([100.0, 0, 1])
        model.advance(1)
        values = model.get(["label", "mode", "enabled", "steps", "heating"])
        assert values == {"label": "kitchen", "mode": 1, "enabled": False, "steps": 6, "heating": False}
        assert isinstance(values["steps"], int) and isinstance(values["enabled"], bool)


def test_fmi3_enumeration_accepts_item_names_and_rejects_undeclared_values(pythonfmu_heater3: Path) -> None:
    with Model(pythonfmu_heater3, step_size_s=STEP) as model:
        assert dict(model.variable("mode").enum_items) == {"off": 1, "eco": 2, "boost": 3}
        model.initialize({"mode": "boost"})
        assert model.get(["mode"]) == {"mode": 3}
        inputs = model.signals(["power", "enabled", "mode"], writable=True)
        with pytest.raises(VariableError, match=r"mode=7 .*items"):
            inputs.write([1.0, 1, 7])
        with pytest.raises(VariableError, match="not one of"):
            model.reset({"mode": "turbo"})


def test_tunable_parameter_changes_between_steps(pythonfmu_heater3: Path) -> None:
    with Model(pythonfmu_heater3, step_size_s=STEP) as model:
        model.initialize()
        inputs = model.signals(["power", "enabled", "mode"], writable=True)
        inputs.write([100.0, 1, 3])
        model.advance(1)
        model.set({"gain": 0.02})  # tunable: allowed mid-run
        model.advance(1)
        room = model.get(["room"])["room"]
        t1 = heater_reference(20.0, 10.0, 100.0, 1.0, 1)
        target = 10.0 + 0.02 * 100.0 / LOSS
        assert room == pytest.approx(target + (t1 - target) * math.exp(-LOSS), abs=1e-12)
        with pytest.raises(VariableError, match="only be set at initialisation"):
            model.set({"ambient": 3.0})


def test_fmi2_string_parameter_and_reset_restore_defaults(pythonfmu_heater2: Path) -> None:
    with Model(pythonfmu_heater2, step_size_s=STEP) as model:
        model.initialize({"label": "cellar"})
        assert model.get(["label"]) == {"label": "cellar"}
        model.reset()
        assert model.get(["label", "steps"]) == {"label": "living room", "steps": 0}


def test_dymola_export_cs_matches_fmpy_and_me_agrees(eta_ctrl_fmus: dict[str, Path]) -> None:
    path = eta_ctrl_fmus["damped_oscillator"]
    reference = simulate_fmu(
        str(path),
        fmi_type="CoSimulation",
        start_values={"f": 3.0},
        stop_time=2.0,
        output_interval=0.01,
        step_size=0.01,
        output=["s", "v"],
    )
    trajectories = {}
    for interface in ("cs", "me"):
        with Model(path, step_size_s=0.01, interface=interface) as model:
            model.initialize({"f": 3.0})
            outputs = model.signals(["s", "v"])
            rows = [outputs.read()]
            for _ in range(200):
                model.advance(1)
                rows.append(outputs.read())
            trajectories[interface] = np.array(rows)
    expected = np.column_stack([reference["s"], reference["v"]])
    np.testing.assert_allclose(trajectories["cs"], expected, rtol=0, atol=1e-12)
    # FMPy's own ME simulation fails on this FMU (zero state nominals); ours integrates it.
    np.testing.assert_allclose(trajectories["me"], trajectories["cs"], atol=5e-4)
    assert np.ptp(trajectories["me"][:, 0]) > 0.3  # it really moved


def test_large_dymola_description_inspects_and_windows_only_binary_is_refused(
    eta_ctrl_fmus: dict[str, Path],
) -> None:
    path = eta_ctrl_fmus["kea_simplified"]
    info = read_model_info(path)
    assert info.fmi_version == "2.0" and "Dymola" in (info.generation_tool or "")
    assert len(info.variables) > 100
    assert "linux64" not in info.platforms
    with pytest.raises(FmuLoadError, match=r"no binary for this platform \(linux64\).*win64"):
        Model(path, step_size_s=1.0)
