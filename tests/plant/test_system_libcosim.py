"""The same coupled system in OSP libcosim (``libcosimpy``): a second independent engine.

libcosim's fixed-step algorithm is a Jacobi master (every slave steps from t to t + H, then the
connected values are transferred); SystemPlant with Jacobi at the same macro step must give the
same trajectories within 1e-9.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.fmu import read_model_info
from bridge.plant.system.plant import SystemPlant
from tests.conftest import example_fmu
from tests.plant.test_system import LOAD, MOTOR, motor_load_ssp, run, system_experiment

libcosim = pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (pip install libcosimpy)")


def libcosim_run(h: float, steps: int) -> np.ndarray:
    """motor.omega, motor.current, load.omega, load.torque after each of ``steps`` macro steps."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    fmus = {"motor": example_fmu("dcmotor", "2.0", "cs"), "load": example_fmu("gearload", "2.0", "cs")}
    refs = {
        n: {v.name: v.value_reference for v in read_model_info(f).variables.values()} for n, f in fmus.items()
    }
    execution = CosimExecution.from_step_size(step_size=round(h * 1e9))
    index = {
        n: execution.add_local_slave(CosimLocalSlave(fmu_path=str(f), instance_name=n))
        for n, f in fmus.items()
    }
    for name, values in (("motor", MOTOR), ("load", LOAD)):
        for variable, value in values.items():
            execution.real_initial_value(index[name], refs[name][variable], value)
    for a, y, b, u in (("motor", "omega", "load", "omega_in"), ("load", "torque", "motor", "load_torque")):
        execution.connect_real_variables(index[a], refs[a][y], index[b], refs[b][u])
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    rows = []
    for _ in range(steps):
        assert execution.step()
        motor = observer.last_real_values(index["motor"], [refs["motor"]["omega"], refs["motor"]["current"]])
        load = observer.last_real_values(index["load"], [refs["load"]["omega"], refs["load"]["torque"]])
        rows.append(motor + load)
    return np.array(rows)


def test_jacobi_matches_osp_libcosim(tmp_path: Path) -> None:
    h, steps = 1e-3, 400
    reference = libcosim_run(h, steps)
    with SystemPlant(system_experiment(str(motor_load_ssp(tmp_path)), tmp_path, h, 1.0)) as plant:
        ours = run(plant, steps)
    names = ["motor.omega", "motor.current", "load.omega", "load.torque"]
    for column, name in enumerate(names):
        np.testing.assert_allclose(ours[1:, column], reference[:, column], rtol=0, atol=1e-9, err_msg=name)
    assert np.max(np.abs(ours[:, 0])) > 10.0  # the motor really turned
