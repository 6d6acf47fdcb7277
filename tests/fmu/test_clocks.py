"""FMI 3.0 clocks that tick, on our clocks3 model (models/clocks3/clocks3.c), against closed forms.

Co-simulation with event mode, model exchange and scheduled execution run the same binary; each clock
kind must tick at the times FMI 3.0 §2.2.9 defines for it, and its clocked variables must show the ticks.
"""

from __future__ import annotations

import math
import zipfile
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest

from bridge.errors import ConfigError, StateFileError
from bridge.fmu import Model
from bridge.fmu.model import Solver
from bridge.models.clocked import clocks_fmu

STOP_S = 3.0
EPS = 1e-9


@pytest.fixture(scope="module", params=["cs", "me", "se"])
def fmu(request: pytest.FixtureRequest) -> Path:
    return clocks_fmu(request.param)


def _upto(times: Iterator[float]) -> list[float]:
    out: list[float] = []
    for t in times:
        if t > STOP_S + EPS:
            return out
        out.append(t)
    return out


def _count(start: float = 0.0) -> Iterator[int]:
    k = int(start)
    while True:
        yield k
        k += 1


def _ticks(model: Model) -> dict[str, list[float]]:
    by_clock: dict[str, list[float]] = defaultdict(list)
    for t, name in model.clock_ticks:
        by_clock[name].append(t)
    return by_clock


def _closed_forms(period: float = 0.4, fixed: float = 0.25, tunable: float = 0.5) -> dict[str, list[float]]:
    const = _upto(0.1 + 0.3 * k for k in _count())
    return {
        "c_ctrl": _upto(0.1 * k for k in _count()),
        "c_const": const,
        "c_fixed": _upto(0.05 + fixed * k for k in _count()),
        "c_calc": _upto(period / 2 + period * k for k in _count()),
        "c_tunable": _upto(tunable * k for k in _count()),
        "c_changing": _upto(0.05 * (k + 1) * (k + 2) for k in _count()),
        "c_countdown": _upto(iter([0.05, *(t + 0.05 for t in const)])),
        "c_out": const[1::2],
    }


def _run(model: Model, values: dict[str, float] | None = None) -> dict[str, list[float]]:
    model.reset(values)
    model.advance(round(STOP_S / model.step_size_s))
    return _ticks(model)


def test_every_clock_kind_ticks_at_its_closed_form(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25) as model:
        ticks = _run(model)
        for name, expected in _closed_forms().items():
            assert ticks[name] == pytest.approx(expected, abs=EPS), name
        assert "trigger" not in ticks  # a triggered clock without a schedule never ticks
        # the clocked variables: tick counts and the time of the last tick
        observed = model.get(
            ["n_ctrl", "n_const", "n_fixed", "n_calc", "n_tunable", "n_changing", "n_countdown"]
        )
        for short, count in observed.items():
            assert count == len(ticks["c_" + short[2:]]), short
        assert model.get(["n_out"])["n_out"] == len(ticks["c_out"])
        assert model.get(["t_changing"])["t_changing"] == pytest.approx(ticks["c_changing"][-1], abs=EPS)
        assert model.get(["t_countdown"])["t_countdown"] == pytest.approx(2.85, abs=EPS)


def test_the_fmu_step_grid_does_not_move_the_ticks(fmu: Path) -> None:
    """A step size that no clock interval divides: the steps are split at the ticks."""
    with Model(fmu, step_size_s=0.07) as model:
        model.reset()
        model.advance(43)  # 3.01 s
        ticks = _ticks(model)
        for name, expected in _closed_forms().items():
            assert ticks[name] == pytest.approx(expected, abs=EPS), name
        assert model.time_s == pytest.approx(3.01)


def test_fixed_intervals_set_by_the_importer_and_calculated_by_the_fmu(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25, clock_intervals={"c_fixed": 0.2}) as model:
        ticks = _run(model, {"period": 0.3, "tunable_period": 0.7})
        expected = _closed_forms(period=0.3, fixed=0.2, tunable=0.7)
        for name in ("c_fixed", "c_calc", "c_tunable"):
            assert ticks[name] == pytest.approx(expected[name], abs=EPS), name


def test_a_tunable_interval_changed_between_ticks_counts_from_that_time(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25) as model:
        model.reset()
        model.advance(3)  # 0.75 s: c_tunable ticked at 0 and 0.5
        model.set({"tunable_period": 0.4})
        model.advance(9)  # to 3.0 s
        expected = [0.0, 0.5, *_upto(0.75 + 0.4 * k for k in _count(1))]
        assert _ticks(model)["c_tunable"] == pytest.approx(expected, abs=EPS)


def test_triggered_clocks_tick_on_the_schedule_and_when_asked(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25, clock_schedule={"trigger": [0.6, 1.3, 1.3]}) as model:
        model.reset()
        model.advance(4)
        model.activate_clock("trigger")  # at 1.0 s, before the next step
        model.advance(8)
        assert _ticks(model)["trigger"] == pytest.approx([0.6, 1.0, 1.3], abs=EPS)
        assert model.get(["n_trigger", "t_trigger"]) == {"n_trigger": 3, "t_trigger": pytest.approx(1.3)}
        with pytest.raises(ConfigError, match=r"'c_const' is not a triggered input clock.*\['trigger'\]"):
            model.activate_clock("c_const")


def test_a_reset_replays_the_same_ticks(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25, reset_policy="auto") as model:
        runs = [_run(model) for _ in range(3)]  # initialise, then fmi reset, then restore
        assert runs[0] == runs[1] == runs[2]
        assert model.get(["n_ctrl"])["n_ctrl"] == 31


def test_saved_states_carry_the_clock_schedule(fmu: Path) -> None:
    with Model(fmu, step_size_s=0.25) as model:
        model.reset()
        model.advance(5)
        state = model.save_state()
        model.advance(7)
        first, log = _ticks(model), model.clock_ticks
        model.restore_state(state)
        model.advance(7)
        model.free_state(state)
        again = _ticks(model)
        assert model.clock_ticks == log  # the ticks after the saved state are not listed twice
        assert again["c_changing"][-1] == first["c_changing"][-1] == pytest.approx(2.8)
        assert model.get(["n_changing"])["n_changing"] == len(first["c_changing"])


def test_a_state_file_is_refused_as_it_cannot_carry_the_clock_schedule(fmu: Path, tmp_path: Path) -> None:
    """A state file holds the FMU's bytes only; the next ticks live in the importer (above). clocks3
    declares no serialisation; this copy of it says it can, so only the clocks refuse it (clocks3
    would return Error from fmi3SerializedFMUStateSize)."""
    with zipfile.ZipFile(fmu) as src:
        xml = src.read("modelDescription.xml").decode()
        assert 'canSerializeFMUState="true"' not in xml
        claims = tmp_path / fmu.name
        with zipfile.ZipFile(claims, "w") as dst:
            for item in src.infolist():
                data = src.read(item)
                if item.filename == "modelDescription.xml":
                    data = xml.replace(
                        'canGetAndSetFMUState="true"',
                        'canGetAndSetFMUState="true" canSerializeFMUState="true"',
                    ).encode()
                dst.writestr(item, data)
    with Model(claims, step_size_s=0.25) as model:
        model.reset()
        model.advance(3)
        assert not model.can_serialize
        with pytest.raises(
            StateFileError, match=r"clocks3 \((CS|ME|SE)\) cannot save .*its clocks tick here"
        ):
            model.state_file()


def _controller_reference(
    setpoints: list[float], agent_h: float, gain: float = 2.0
) -> list[tuple[float, float]]:
    """x' = -x + u, u := gain * (r - x) at every 0.1 s, r changed by the agent every agent_h:
    the exact solution, event by event. Returns (x, u) after each agent sample."""
    x = u = 0.0
    t, out = 0.0, []
    ctrl = 0
    for j, r in enumerate(setpoints):
        end = (j + 1) * agent_h
        while ctrl * 0.1 <= end + EPS:
            tick = ctrl * 0.1
            if tick >= t - EPS:
                x = u + (x - u) * math.exp(-(tick - t))
                t = tick
                u = gain * (r - x)
            ctrl += 1
        x = u + (x - u) * math.exp(-(end - t))
        t = end
        out.append((x, u))
    return out


@pytest.mark.parametrize(
    ("interface", "solver", "tolerance"),
    [("cs", "cvode", 1e-12), ("me", "cvode", 2e-5), ("me", "rk4", 1e-8)],
)
def test_a_clocked_controller_samples_at_its_own_rate_while_the_agent_samples_at_another(
    interface: str, solver: Solver, tolerance: float
) -> None:
    """The FMU's controller runs every 0.1 s; the agent sets r and reads x every 0.25 s. Model
    exchange integrates the plant with our solvers (CVode at its tolerance, RK4 in 0.025 s steps)."""
    setpoints = [1.0, 1.0, -0.5, 0.3, 0.3, 2.0, 0.0, 1.5, -1.0, 0.7, 0.2, 0.9]
    with Model(clocks_fmu(interface), step_size_s=0.25, solver=solver, solver_substeps=10) as model:
        model.reset()
        observed = []
        for r in setpoints:
            model.set({"r": r})
            model.advance(1)
            values = model.get(["x", "u", "t_ctrl", "n_ctrl"])
            observed.append(values)
        reference = _controller_reference(setpoints, 0.25)
        for j, (values, (x, u)) in enumerate(zip(observed, reference, strict=True)):
            t = 0.25 * (j + 1)
            assert values["x"] == pytest.approx(x, rel=tolerance, abs=tolerance), t
            assert values["u"] == pytest.approx(u, rel=tolerance, abs=tolerance), t
            last_tick = math.floor(t / 0.1 + EPS) * 0.1
            assert values["t_ctrl"] == pytest.approx(last_tick, abs=EPS)  # the controller's own grid
            assert values["n_ctrl"] == round(last_tick / 0.1) + 1
        assert len({round(v["u"], 12) for v in observed}) > 6  # u changed between the agent's samples


def test_bad_clock_settings_are_refused_saying_what_is_allowed(fmu: Path) -> None:
    with pytest.raises(ConfigError, match=r"interval of clock 'c_const' cannot be set.*\['c_fixed'\]"):
        Model(fmu, step_size_s=0.25, clock_intervals={"c_const": 0.2})
    with pytest.raises(ConfigError, match=r"clock_schedule names 'c_ctrl'.*\['trigger'\]"):
        Model(fmu, step_size_s=0.25, clock_schedule={"c_ctrl": [0.5]})
    with pytest.raises(ConfigError, match=r"increasing order"):
        Model(fmu, step_size_s=0.25, clock_schedule={"trigger": [0.5, 0.2]})


@pytest.mark.parametrize("interface", ["cs", "me"])
def test_the_fmus_own_time_event_splits_the_step_where_it_says(interface: str) -> None:
    """The FMU announces its next time event (nextEventTime) besides its clocks' ticks."""
    with Model(clocks_fmu(interface), step_size_s=0.25) as model:
        model.reset({"alarm_time": 1.737})
        model.advance(6)
        assert model.get(["t_alarm"])["t_alarm"] == -1.0
        model.advance(1)  # 1.5 -> 1.75 s, split at 1.737 s
        assert model.get(["t_alarm"])["t_alarm"] == pytest.approx(1.737, abs=1e-12)
        assert _ticks(model)["c_ctrl"][-1] == pytest.approx(1.7)  # the clocks' grid is unchanged


def test_an_event_the_fmu_did_not_announce_is_handled_at_the_end_of_the_step() -> None:
    """Co-simulation: a doStep that passes the FMU's unannounced time event returns
    eventHandlingNeeded; the event is handled at the end of that step (1.75 s)."""
    with Model(clocks_fmu("cs"), step_size_s=0.25) as model:
        model.reset({"alarm_time": 1.737, "announce_alarm": 0.0})
        model.advance(7)
        assert model.get(["t_alarm"])["t_alarm"] == pytest.approx(1.75, abs=1e-12)
