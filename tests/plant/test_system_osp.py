"""OSP system structures to the letter: decimation as libcosim maps it, refusals by name, and the
file's steps and start time kept under every override (docs/systems.md, "SSP and OSP support")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant
from tests.plant.ssp_semantics import motor_load, osp_dir, write

NAMES = ["motor.omega", "motor.current", "load.omega", "load.torque"]
BASE_S = 1e-3


def slower_motor(directory: Path, step: str, *, replace: tuple[str, str] = ("", "")) -> Path:
    """The motor and load of ``osp_dir`` with the motor's ``stepSize`` set (the load at the base step)."""
    path = osp_dir(directory)
    text = path.read_text().replace(
        '<Simulator name="motor" source="dcmotor.fmu">',
        f'<Simulator name="motor" source="dcmotor.fmu" stepSize="{step}">',
    )
    path.write_text(text.replace(*replace) if replace[0] else text)
    return path


def experiment(path: Path, **model: Any) -> Any:
    """The system file run as it is, with a component override (the motor's feedthrough)."""
    data: dict[str, Any] = {
        "model": {"fmu": str(path), "episode_duration": 1.0, **model},
        "observations": {"outputs": NAMES},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    return parse_experiment(data, source=path.parent / "e.yaml")


def ours(path: Path, macro_steps: int) -> tuple[np.ndarray, SystemPlant]:
    with SystemPlant(experiment(path)) as plant:
        plant.bind([], NAMES)
        rows = [plant.reset({}, None)] + [plant.step(None) for _ in range(macro_steps)]
    return np.array(rows), plant


def libcosim_rows(path: Path, base_steps: int) -> np.ndarray:
    """libcosim reading the file itself: the outputs after each base step."""
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (pip install libcosimpy)")
    from libcosimpy.CosimExecution import CosimExecution

    from tests.plant import test_system_ssp_semantics as semantics

    execution = CosimExecution.from_osp_config_file(str(path))
    saved, semantics.STEPS = semantics.STEPS, base_steps
    try:
        return semantics._observe(execution)
    finally:
        semantics.STEPS = saved


@pytest.mark.parametrize(("step", "every", "warned"), [("0.002", 2, False), ("0.0027", 2, True)])
def test_a_slower_osp_simulator_steps_at_its_own_step_as_libcosim(
    tmp_path: Path, step: str, every: int, warned: bool
) -> None:
    """The macro step is the slowest simulator's step; the load steps `every` times inside it; a
    step that is not a whole number of base steps is rounded down, as libcosim, with a warning
    naming both (before, the motor was clamped to the base step, far from libcosim)."""
    path = slower_motor(tmp_path / "osp", step)
    macro_steps = 100
    rows, plant = ours(path, macro_steps)
    reference = libcosim_rows(path, macro_steps * every)
    assert plant.timing.step_size_s == pytest.approx(every * BASE_S)
    assert plant.system.components["motor"].step_size_s == pytest.approx(every * BASE_S)
    assert plant.system.components["load"].step_size_s == pytest.approx(BASE_S)
    np.testing.assert_allclose(rows[1:], reference[every - 1 :: every], rtol=0, atol=1e-9)
    assert np.max(np.abs(rows[:, 0])) > 10.0  # the motor really turned
    rounded = [w for w in plant.warnings if "not a whole number of BaseStepSize" in w]
    assert bool(rounded) == warned
    if warned:
        assert f"stepSize {step} s" in rounded[0] and f"every {every} base steps" in rounded[0]


def test_osp_steps_that_do_not_divide_the_largest_are_refused_by_name(tmp_path: Path) -> None:
    load = '<Simulator name="load" source="gearload.fmu">'
    path = slower_motor(
        tmp_path / "osp",
        "0.003",
        replace=(load, '<Simulator name="load" source="gearload.fmu" stepSize="0.002">'),
    )
    with pytest.raises(
        ConfigError, match=r"simulators 'load' \(every 2 base steps.*'motor' \(every 3"
    ) as info:
        ours(path, 1)
    assert "give stepSizes that divide the largest one" in str(info.value)


@pytest.mark.parametrize(
    ("replace", "expected"),
    [
        (
            ("<Algorithm>fixedStep</Algorithm>", "<Algorithm>ecco</Algorithm>"),
            "Algorithm 'ecco' is not supported",
        ),
        (("<VariableConnection>", '<VariableConnection powerBond="shaft">'), "power bonds \\(powerBond in"),
        (("</Connections>", "</Connections><PowerBonds/>"), "power bonds \\(PowerBonds in"),
    ],
)
def test_ecco_and_power_bonds_are_refused_by_name(
    tmp_path: Path, replace: tuple[str, str], expected: str
) -> None:
    path = slower_motor(tmp_path / "osp", "0.001", replace=replace)
    with pytest.raises(ConfigError, match=expected) as info:
        ours(path, 1)
    assert str(path) in str(info.value)


def test_the_file_start_time_and_steps_survive_component_overrides(tmp_path: Path) -> None:
    """OSP StartTime and SSP startTime start the run; `--no-feedthrough X` (a component entry) keeps
    X's stepSize; model.start_time, where the experiment sets it, still wins."""
    from bridge.cli.system import _experiment, summary

    osp = slower_motor(
        tmp_path / "osp", "0.002", replace=("<StartTime>0.0</StartTime>", "<StartTime>1.5</StartTime>")
    )
    exp = _experiment(osp, no_feedthrough=["motor"])
    with SystemPlant(exp) as plant:
        steps = {c["name"]: c["step_size_s"] for c in summary(plant)["components"]}
        assert steps == pytest.approx({"motor": 2 * BASE_S, "load": BASE_S})
        plant.bind([], NAMES)
        plant.reset({}, None)
        assert plant.time_s == 1.5
        plant.step(None)
        assert plant.time_s == pytest.approx(1.5 + 2 * BASE_S)
    ssp = write(tmp_path / "s.ssp", motor_load().replace('startTime="0"', 'startTime="0.25"'))
    with SystemPlant(_experiment(ssp, no_feedthrough=["motor"])) as plant:
        assert plant.timing.start_time_s == 0.25
    with SystemPlant(experiment(ssp, step_size=BASE_S, start_time=0.0)) as plant:
        assert plant.timing.start_time_s == 0.0


def test_a_component_step_longer_than_the_macro_step_is_refused(tmp_path: Path) -> None:
    """Before, such a step was clamped to the macro step without a word."""
    path = slower_motor(tmp_path / "osp", "0.002")
    longer = r"motor\.step_size: 0\.002 s is longer than the macro step 0\.001 s"
    with pytest.raises(ConfigError, match=longer):
        SystemPlant(experiment(path, step_size=BASE_S))
