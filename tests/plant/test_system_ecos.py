"""SSP transformations and units against Ecos (``ecospy``), a second independent engine reading the
same SSP files with its own parser and its own master loop.

Ecos applies ``LinearTransformation`` on connections and reads parameter bindings; it does not
convert units (neither on connectors nor on bound values), so, as with libcosim, a file with units
runs here and Ecos runs the same file with the conversion written out (a ``LinearTransformation``
or the value in SI).

What Ecos reports for an output with direct feedthrough is read at another moment than what it
carries over the connection: after a macro step it reads the outputs, passes them on (setting the
inputs of ``t + H``), and ``get_real`` then asks the FMU again, which recomputes the output from the
new inputs. The load's ``torque`` feeds through from its ``omega_in``: Ecos's value is the load's
output re-read after the exchange, while the motor was driven by the value read before it (libcosim
and this project report that one). The states agree to the last bit either way.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.config import parse_experiment
from bridge.plant.system.plant import SystemPlant
from tests.plant.ssp_semantics import motor_load, unit, write
from tests.plant.test_system_ssp_semantics import GRAM_M2, LINEAR_TORQUE, MOTOR_J, NAMES, STEPS, UNITS, H

TORQUE = NAMES.index("load.torque")
STATES = [c for c, name in enumerate(NAMES) if c != TORQUE]


def ours(ssp: Path, tmp_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The outputs after each macro step as recorded here, and the load's torque re-read after the
    exchange of that macro step (its inputs of t + H set), the moment Ecos reads it at."""
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": NAMES},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        plant.bind([], NAMES)
        plant.reset({}, None)
        load = plant.plants["load"]
        rows, reread = [], []
        for _ in range(STEPS):
            rows.append(plant.step(None))
            after = load.settle(plant.master._gather("load").tolist())  # the inputs of t + H
            reread.append(after[load.output_names.index("torque")])
    return np.array(rows), np.array(reread)


def ecos(ssp: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> np.ndarray:
    """The four outputs after each macro step, Ecos reading ``ssp`` itself (its parameter set "p")."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # Ecos unpacks the archive there and leaves it
    ecospy = pytest.importorskip("ecospy", reason="ecospy is not installed (pip install ecospy)")
    simulation = ecospy.EcosSimulation(step_size=H, ssp_path=str(ssp))
    try:
        simulation.init(parameter_set="p")
        rows = []
        for _ in range(STEPS):
            simulation.step(1)
            rows.append([simulation.get_real(name.replace(".", "::")) for name in NAMES])
    finally:
        simulation.terminate()
        simulation.free()
    return np.array(rows)


def same(ours_run: tuple[np.ndarray, np.ndarray], theirs: np.ndarray) -> None:
    recorded, reread = ours_run
    for column in STATES:
        np.testing.assert_allclose(
            recorded[:, column], theirs[:, column], rtol=0, atol=1e-9, err_msg=NAMES[column]
        )
    np.testing.assert_allclose(reread, theirs[:, TORQUE], rtol=0, atol=1e-9, err_msg="load.torque")


def test_linear_transformation_matches_ecos(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ssp = write(tmp_path / "linear.ssp", motor_load(torque=LINEAR_TORQUE))
    run = ours(ssp, tmp_path)
    theirs = ecos(ssp, tmp_path, monkeypatch)
    same(run, theirs)
    plain = ours(write(tmp_path / "plain.ssp", motor_load()), tmp_path)[0]
    assert np.max(np.abs(run[0][:, 0] - plain[:, 0])) > 1.0  # the transformation does act
    # the torque Ecos reports is not the one it passed to the motor (read before the exchange)
    assert np.max(np.abs(run[0][:, TORQUE] - theirs[:, TORQUE])) > 1e-3


def test_unit_conversion_and_transformation_match_ecos(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """rad/s to rpm declared on the connectors, run here; Ecos runs the equivalent factor."""
    with_units = motor_load(torque=LINEAR_TORQUE, units=UNITS, omega_unit=("rad/s", "rpm"))
    factor = 1 / (2 * math.pi / 60)
    explicit = motor_load(omega=f'<ssc:LinearTransformation factor="{factor!r}"/>', torque=LINEAR_TORQUE)
    converted = ours(write(tmp_path / "units.ssp", with_units), tmp_path)
    same(converted, ecos(write(tmp_path / "explicit.ssp", explicit), tmp_path, monkeypatch))


def test_an_offset_unit_and_a_transformation_match_ecos(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A unit with an offset and a linear map on the same connection: SSP converts first, then
    transforms, ``10 * (v - 3) / 2 + 1``: Ecos runs that as one LinearTransformation."""
    units = unit("rad/s", rad=1, s=-1) + unit("shifted", factor=2.0, offset=3.0, rad=1, s=-1)
    text = motor_load(
        omega='<ssc:LinearTransformation factor="0.01" offset="1"/>',
        units=units,
        omega_unit=("rad/s", "shifted"),
    )
    explicit = motor_load(omega='<ssc:LinearTransformation factor="0.005" offset="0.985"/>')
    run = ours(write(tmp_path / "order.ssp", text), tmp_path)
    same(run, ecos(write(tmp_path / "explicit.ssp", explicit), tmp_path, monkeypatch))


def test_a_bound_value_in_another_unit_matches_ecos(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The motor's inertia bound as 2 g.m2 here; Ecos binds 0.002 kg.m2."""
    text = motor_load(units=GRAM_M2)
    grams = text.replace(MOTOR_J, MOTOR_J.replace('value="0.002"', 'value="2.0" unit="g.m2"'))
    converted = ours(write(tmp_path / "grams.ssp", grams), tmp_path)
    same(converted, ecos(write(tmp_path / "si.ssp", motor_load()), tmp_path, monkeypatch))
