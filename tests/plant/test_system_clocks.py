"""A clocked FMI 3.0 FMU (clocks3) as a component of a system: its clocks tick at their own times
inside the macro steps, the component's ``clock_intervals`` and ``clock_schedule`` are honoured in
this process and in a component node, and clock settings that cannot be honoured are refused by
name. Counters against their closed forms; the component's outputs against the same FMU run alone
as an env, bit for bit."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import load_experiment, parse_experiment
from bridge.models import example_fmu
from bridge.models.clocked import clocks_fmu
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from tests.conftest import Loopback
from tests.plant.ssp_files import ssd_text, write_ssp
from tests.plant.test_system_nodes import serve

MACRO = 0.06  # the agent's sample; clocks3 steps 0.02 inside it (multi-rate)
H = 0.02
SAMPLES = 20
FIXED = 0.2  # c_fixed: set by the component (the XML's is 0.25)
PERIOD = 0.3  # c_calc: calculated by the FMU from its parameter: ticks at PERIOD/2 + PERIOD k
SCHEDULE = (0.5, 1.1)
AGENT_TICKS = (3, 7)
CLOCKED = ["x", "u", "n_fixed", "n_calc", "n_const", "n_trigger", "t_trigger"]


def _actions() -> list[np.ndarray]:
    return [
        np.array([0.5 * math.sin(j), 1.0 if j in AGENT_TICKS else 0.0], dtype=np.float32)
        for j in range(SAMPLES)
    ]


def _system(interface: str, **component: Any) -> dict[str, Any]:
    clk = {
        "fmu": f"example:clocks3:3.0:{interface}",
        "interface": interface,
        "step_size": H,
        "parameters": {"period": PERIOD},
        "clock_intervals": {"c_fixed": FIXED},
        "clock_schedule": {"trigger": list(SCHEDULE)},
        **component,
    }
    return {
        "model": {"fmu": "system", "step_size": MACRO, "episode_duration": MACRO * SAMPLES},
        "system": {
            "components": {"clk": clk, "ft": {"fmu": "example:feedthrough:3.0"}},
            "connections": ["clk.x -> ft.u"],
        },
        "actions": {"inputs": ["clk.r", "clk.trigger"], "low": {"clk.r": -1.0}, "high": {"clk.r": 1.0}},
        "observations": {"outputs": [f"clk.{n}" for n in CLOCKED] + ["ft.y"], "scale": "none"},
        "reward": {"expression": "-abs(clk.x - 0.5)"},
    }


def _alone(interface: str) -> dict[str, Any]:
    """clocks3 with the same settings as the only FMU of an experiment."""
    return {
        "model": {
            "fmu": f"example:clocks3:3.0:{interface}",
            "step_size": H,
            "sampling_time": MACRO,
            "episode_duration": MACRO * SAMPLES,
            "parameters": {"period": PERIOD},
            "clock_intervals": {"c_fixed": FIXED},
            "clock_schedule": {"trigger": list(SCHEDULE)},
        },
        "actions": {"inputs": ["r", "trigger"], "low": {"r": -1.0}, "high": {"r": 1.0}},
        "observations": {"outputs": CLOCKED, "scale": "none"},
        "reward": {"expression": "-abs(x - 0.5)"},
    }


def _episodes(env: FmuEnv) -> np.ndarray:
    rows = []
    for seed in (0, 1):  # the second episode replays the clocks from the reset
        rows.append(env.reset(seed=seed)[0])
        rows += [env.step(a)[0] for a in _actions()]
    return np.array(rows, dtype=np.float64)


def _check_closed_form(rows: np.ndarray) -> None:
    """No tick of these clocks falls on a sample time (0.06 j), so each count is unambiguous."""
    for episode in range(2):
        for j in range(SAMPLES + 1):
            t = j * MACRO
            obs = dict(zip(CLOCKED, rows[episode * (SAMPLES + 1) + j]))

            def ticks(first: float, interval: float, t: float = t) -> int:
                return math.floor((t - first) / interval) + 1 if t >= first else 0

            assert obs["n_fixed"] == ticks(0.05, FIXED), (episode, j)
            assert obs["n_calc"] == ticks(PERIOD / 2, PERIOD), (episode, j)
            assert obs["n_const"] == ticks(0.1, 0.3), (episode, j)
            assert obs["n_trigger"] == sum(s <= t for s in SCHEDULE) + sum(k < j for k in AGENT_TICKS)


@pytest.mark.parametrize("interface", ["cs", "me", "se"])
def test_a_clocked_component_ticks_as_the_fmu_alone_with_its_clock_settings(interface: str) -> None:
    with FmuEnv(parse_experiment(_alone(interface))) as env:
        alone = _episodes(env)
    _check_closed_form(alone)
    with FmuEnv(parse_experiment(_system(interface))) as env:
        assert isinstance(env.plant, SystemPlant)
        rows = _episodes(env)
    _check_closed_form(rows[:, : len(CLOCKED)])
    np.testing.assert_array_equal(rows[:, : len(CLOCKED)], alone)
    # the connection carries x (held over the macro step, Jacobi): ft.y is x a sample late
    np.testing.assert_array_equal(rows[1:SAMPLES, -1], rows[: SAMPLES - 1, 0])


@pytest.mark.parametrize("interface", ["cs", "me", "se"])
def test_fixed_point_iteration_rolls_the_clocks_back_with_the_component(interface: str) -> None:
    """A loop through the clocked component, solved by iteration with rollback every macro step:
    each clock ticks once at each of its times (counters and the tick log), however many tries."""
    data = _system(interface)
    data["system"]["connections"].append("ft.y -> clk.r")
    data["system"]["iteration"] = {"max_iterations": 5, "tolerance": 1e-12}
    data["actions"] = {"inputs": ["clk.trigger"]}
    with FmuEnv(parse_experiment(data)) as env:
        rows = []
        for _ in range(2):
            rows.append(env.reset(seed=0)[0])
            rows += [env.step(a[1:])[0] for a in _actions()]
            log = env.plant.plants["clk"].model.clock_ticks  # type: ignore[attr-defined]
            end = MACRO * SAMPLES + 1e-9
            by_clock = {c: [t for t, name in log if name == c] for c in ("c_ctrl", "c_fixed", "trigger")}
            assert by_clock["c_ctrl"] == pytest.approx([0.1 * k for k in range(13)])
            assert by_clock["c_fixed"] == pytest.approx([0.05 + FIXED * k for k in range(6)])
            agent = [MACRO * k for k in AGENT_TICKS]
            assert by_clock["trigger"] == pytest.approx(sorted([*SCHEDULE, *agent]))
            assert all(t <= end for t, _ in log)
        _check_closed_form(np.array(rows)[:, : len(CLOCKED)])


def test_fixed_point_iteration_rolls_a_clocked_component_node_back(net: Loopback, tmp_path: Path) -> None:
    """The same loop with the clocked component in a node: the node saves and restores its plant
    every macro step; the same observations as in process, bit for bit."""

    def looped(**component: Any) -> dict[str, Any]:
        data = _system("cs", **component)
        data["system"]["connections"].append("ft.y -> clk.r")
        data["system"]["iteration"] = {"max_iterations": 5, "tolerance": 1e-12}
        data["actions"] = {"inputs": ["clk.trigger"]}
        return data

    def run(env: FmuEnv) -> np.ndarray:
        rows = []
        for _ in range(2):
            rows.append(env.reset(seed=0)[0])
            rows += [env.step(a[1:])[0] for a in _actions()]
        return np.array(rows, dtype=np.float64)

    with FmuEnv(parse_experiment(looped())) as env:
        expected = run(env)
    there = tmp_path / "looped.yaml"
    there.write_text(yaml.safe_dump(looped(node="clk-loop")))
    with serve(there, net, "clk"):
        remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)
        with FmuEnv(there, plant=SystemPlant(load_experiment(there), remote=remote)) as env:
            got = run(env)
    _check_closed_form(got[:, : len(CLOCKED)])
    np.testing.assert_array_equal(got, expected)


def test_an_ssp_component_takes_its_clock_settings_from_the_system_section(tmp_path: Path) -> None:
    """SSP 1.0 has no place for clock settings: a system: section beside it adds them by name."""
    ssd = ssd_text(
        {
            "clk": ("resources/clocks3.fmu", {"r": "input", "x": "output"}, {}),
            "ft": ("resources/feedthrough.fmu", {"u": "input", "y": "output"}, {}),
        },
        [("clk", "x", "ft", "u")],
    )
    fmus = {
        "resources/clocks3.fmu": clocks_fmu("cs"),
        "resources/feedthrough.fmu": example_fmu("feedthrough", "3.0", "cs"),
    }
    ssp = write_ssp(tmp_path / "clocked.ssp", ssd, fmus)
    data = _system("cs")
    clk = data["system"]["components"]["clk"]
    del clk["fmu"]
    data["system"] = {"components": {"clk": clk}}
    data["model"]["fmu"] = str(ssp)
    with FmuEnv(parse_experiment(data)) as env:
        from_ssp = _episodes(env)
    with FmuEnv(parse_experiment(_system("cs"))) as env:
        np.testing.assert_array_equal(from_ssp, _episodes(env))
    _check_closed_form(from_ssp[:, : len(CLOCKED)])


@pytest.mark.parametrize("isolate", [False, True], ids=["in_node", "isolated_in_node"])
def test_a_clocked_component_in_a_node_honours_its_clock_settings(
    net: Loopback, tmp_path: Path, isolate: bool
) -> None:
    here = parse_experiment(_system("cs"))
    data = _system("cs", node=f"clk-node-{isolate:d}")
    there = tmp_path / "there.yaml"
    there.write_text(yaml.safe_dump(data))
    with FmuEnv(here) as env:
        expected = _episodes(env)
    with serve(there, net, "clk", extra=("--isolate",) if isolate else ()):
        remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=60.0)
        with FmuEnv(there, plant=SystemPlant(load_experiment(there), remote=remote)) as env:
            assert type(env.plant.plants["clk"]).__name__ == "RemotePlant"  # type: ignore[attr-defined]
            got = _episodes(env)
    _check_closed_form(got[:, : len(CLOCKED)])
    np.testing.assert_array_equal(got, expected)


def test_clock_settings_a_system_cannot_honour_are_refused_by_name() -> None:
    top = _system("cs")
    top["model"]["clock_schedule"] = {"trigger": [0.5]}
    refused = r"model\.clock_schedule: a system's clocks .*system\.components\.NAME"
    with pytest.raises(ConfigError, match=refused):
        FmuEnv(parse_experiment(top))
    wrong = _system("cs", clock_schedule={"c_const": [0.5]})
    with pytest.raises(
        ConfigError, match=r"system\.components\.clk: clocks3: clock_schedule names 'c_const'.*\['trigger'\]"
    ):
        FmuEnv(parse_experiment(wrong))
    unclocked = _system("cs")
    unclocked["system"]["components"]["ft"]["clock_intervals"] = {"c_fixed": 0.2}
    with pytest.raises(ConfigError, match=r"system\.components\.ft: .*need FMI 3\.0 input clocks"):
        FmuEnv(parse_experiment(unclocked))
