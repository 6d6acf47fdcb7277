"""``Model.save_state``/``restore_state``/``free_state``: rollback of one FMU instance.

Going back to a saved state and stepping again with the same inputs repeats the outputs bit for
bit (co-simulation and model exchange); other inputs after the rollback give what a fresh run
with those inputs gives; FMUs that cannot save say so.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.errors import FmuError
from bridge.fmu import Model
from tests.conftest import example_fmu


def run(model: Model, voltage: float, steps: int) -> list[float]:
    out = []
    for _ in range(steps):
        model.set({"voltage": voltage})
        model.advance(1)
        out.append(model.get(["omega"])["omega"])
    return out


@pytest.mark.parametrize("interface", ["cs", "me"])
def test_restore_repeats_the_steps_after_the_save(interface: str) -> None:
    with Model(example_fmu("dcmotor", "2.0", interface), step_size_s=1e-3) as model:
        model.reset()
        run(model, 12.0, 20)
        state = model.save_state()
        first = run(model, 12.0, 30)
        model.restore_state(state)
        assert model.step_index == 20 and model.time_s == pytest.approx(0.02)
        assert run(model, 12.0, 30) == first
        model.restore_state(state)  # again: a state stays until freed
        other = run(model, -6.0, 30)
        model.free_state(state)
        model.free_state(state)  # twice is harmless
        with pytest.raises(FmuError, match="freed state"):
            model.restore_state(state)
    with Model(example_fmu("dcmotor", "2.0", interface), step_size_s=1e-3) as fresh:
        fresh.reset()
        run(fresh, 12.0, 20)
        assert run(fresh, -6.0, 30) == other  # the rollback left nothing of the discarded steps


def test_an_fmu_without_state_functions_cannot_save(tmp_path: Path) -> None:
    import zipfile

    source = example_fmu("dcmotor", "2.0", "cs")
    target = tmp_path / "nostate.fmu"
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'canGetAndSetFMUstate="true"', b'canGetAndSetFMUstate="false"')
            zout.writestr(item, data)
    with Model(target, step_size_s=1e-3) as model:
        model.reset()
        assert not model.can_restore
        with pytest.raises(FmuError, match=r"cannot save the state: the FMU cannot get and set its state"):
            model.save_state()
