"""Tests of the example FMUs built by bridge.models.

The archives are driven with FMPy directly (simulate_fmu and FMU1Slave/FMU2Slave/FMU3Slave), never
through bridge.fmu, and compared with independent references: scipy's solve_ivp for the cart-pole,
the matrix exponential for the DC motor, closed-form bounce times for the bouncing ball.
"""

from __future__ import annotations

import ctypes
import re
import shutil
import threading
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fmpy import calloc, extract, free, read_model_description, simulate_fmu
from fmpy.fmi1 import (
    FMICallException,
    FMU1Slave,
    fmi1CallbackAllocateMemoryTYPE,
    fmi1CallbackFreeMemoryTYPE,
    fmi1CallbackFunctions,
    fmi1CallbackLoggerTYPE,
)
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2LastSuccessfulTime,
    fmi2Terminated,
)
from fmpy.fmi3 import FMU3Slave, fmi3ValueReference
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from bridge import models
from bridge.errors import BridgeError, ConfigError, DependencyMissing
from bridge.models import build as model_build
from bridge.models import sources as model_sources

VARIANTS = [(v.name, v.fmi_version, v.interface) for v in models.list_variants()]
Fmus = dict[tuple[str, str, str], Path]
ERROR, DISCARD = 3, 2
STATE_NAMES = ("x", "x_dot", "theta", "theta_dot")


def variant_id(variant: tuple[str, str, str]) -> str:
    return "-".join(variant)


@pytest.fixture(scope="session")
def fmus() -> Fmus:
    """Every example FMU, built once per session (or taken from the per-user cache)."""
    return dict(zip(VARIANTS, models.build_all(), strict=True))


# --- FMPy helpers -------------------------------------------------------------------------------


@dataclass
class Slave:
    """An instantiated co-simulation FMU, its value references and the log messages it sent."""

    fmu: Any
    vr: dict[str, int]
    log: list[tuple[int, str, str]] = field(default_factory=list)

    def messages(self) -> str:
        return "\n".join(message for _, _, message in self.log)


OpenSlave = Callable[..., Slave]


@pytest.fixture
def open_slave(tmp_path: Path) -> Iterator[OpenSlave]:
    """Factory: extract and instantiate a CS FMU with a log-collecting logger; freed at teardown."""
    opened: list[Slave] = []

    def factory(path: Path, *, logging_on: bool = False) -> Slave:
        description = read_model_description(str(path))
        directory = extract(str(path), unzipdir=str(tmp_path / f"fmu{len(opened)}"))
        kwargs = {
            "guid": description.guid,
            "unzipDirectory": directory,
            "modelIdentifier": description.coSimulation.modelIdentifier,
            "instanceName": "test",
        }
        vr = {v.name: v.valueReference for v in description.modelVariables}
        slave = Slave(fmu=None, vr=vr)

        def collect(status: int, category: bytes, message: bytes) -> None:
            slave.log.append((status, category.decode(), message.decode()))

        version = description.fmiVersion
        if version == "3.0":
            slave.fmu = FMU3Slave(**kwargs)
            slave.fmu.instantiate(
                loggingOn=logging_on, logMessage=lambda env, st, cat, msg: collect(st, cat, msg)
            )
        elif version == "2.0":
            slave.fmu = FMU2Slave(**kwargs)
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = fmi2CallbackLoggerTYPE(lambda env, name, st, cat, msg: collect(st, cat, msg))
            callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            slave.fmu.instantiate(callbacks=callbacks, loggingOn=logging_on)
        else:
            slave.fmu = FMU1Slave(**kwargs)
            functions = fmi1CallbackFunctions()
            functions.logger = fmi1CallbackLoggerTYPE(lambda c, name, st, cat, msg: collect(st, cat, msg))
            functions.allocateMemory = fmi1CallbackAllocateMemoryTYPE(calloc)
            functions.freeMemory = fmi1CallbackFreeMemoryTYPE(free)
            slave.fmu.instantiate(functions=functions, loggingOn=logging_on)
        opened.append(slave)
        return slave

    yield factory
    for slave in opened:
        slave.fmu.freeInstance()


def initialize(slave: Slave, start_time: float = 0.0) -> None:
    fmu = slave.fmu
    if isinstance(fmu, FMU1Slave):
        fmu.initialize(tStart=start_time)
        return
    if isinstance(fmu, FMU2Slave):
        fmu.setupExperiment(startTime=start_time)
        fmu.enterInitializationMode()
    else:
        fmu.enterInitializationMode(startTime=start_time)
    fmu.exitInitializationMode()


def set_real(slave: Slave, name: str, value: float) -> None:
    setter = slave.fmu.setFloat64 if isinstance(slave.fmu, FMU3Slave) else slave.fmu.setReal
    setter([slave.vr[name]], [value])


def get_reals(slave: Slave, names: Sequence[str]) -> np.ndarray:
    getter = slave.fmu.getFloat64 if isinstance(slave.fmu, FMU3Slave) else slave.fmu.getReal
    return np.array(getter([slave.vr[n] for n in names]))


def fmi1_do_step(fmu: FMU1Slave, t: float, h: float) -> None:
    """fmiDoStep through our own ctypes prototype: FMPy 0.3.32 declares its result as a string
    (fmi1String), so any status other than OK would be dereferenced as a pointer and crash."""
    function = fmu.dll[f"{fmu.modelIdentifier}_fmiDoStep"]  # a fresh function object, FMPy's stays untouched
    function.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_char]
    function.restype = ctypes.c_int
    status = function(fmu.component, t, h, b"\x01")
    if status > 1:
        raise FMICallException("fmiDoStep", status)


def do_step(slave: Slave, t: float, h: float) -> bool:
    """One doStep; returns True when the FMU requested termination (FMI 2.0 signals it via Discard)."""
    if isinstance(slave.fmu, FMU3Slave):
        return bool(slave.fmu.doStep(t, h)[1])
    if isinstance(slave.fmu, FMU1Slave):
        fmi1_do_step(slave.fmu, t, h)
        return False
    try:
        slave.fmu.doStep(t, h)
    except FMICallException as exc:
        if exc.status == DISCARD and isinstance(slave.fmu, FMU2Slave):
            return bool(slave.fmu.getBooleanStatus(fmi2Terminated))
        raise
    return False


def as_array(result: np.ndarray, names: Sequence[str]) -> np.ndarray:
    return np.column_stack([result[n] for n in names])


def input_signal(times: Sequence[float], **columns: Sequence[float]) -> np.ndarray:
    dtype = [("time", np.float64)] + [(name, np.float64) for name in columns]
    return np.array(list(zip(times, *columns.values(), strict=True)), dtype=dtype)


# --- references ---------------------------------------------------------------------------------


def cartpole_derivatives(
    state: np.ndarray,
    force: float,
    *,
    m_cart: float = 1.0,
    m_pole: float = 0.1,
    length: float = 0.5,
    g: float = 9.8,
) -> list[float]:
    """gymnasium CartPole's equations (classic_control/cartpole.py), written out independently."""
    _, x_dot, theta, theta_dot = state
    total_mass = m_cart + m_pole
    polemass_length = m_pole * length
    sin, cos = np.sin(theta), np.cos(theta)
    temp = (force + polemass_length * theta_dot**2 * sin) / total_mass
    thetaacc = (g * sin - cos * temp) / (length * (4.0 / 3.0 - m_pole * cos**2 / total_mass))
    xacc = temp - polemass_length * thetaacc * cos / total_mass
    return [x_dot, xacc, theta_dot, thetaacc]


def piecewise_solution(
    rhs: Callable[[np.ndarray, Any], Sequence[float]],
    x0: Sequence[float],
    edges: Sequence[float],
    inputs: Sequence[Any],
    t_eval: np.ndarray,
) -> np.ndarray:
    """x' = rhs(x, u) with u = inputs[k] on [edges[k], edges[k+1]], by DOP853 at rtol = atol = 1e-12."""
    out = np.full((len(t_eval), len(x0)), np.nan)
    x = np.asarray(x0, dtype=float)
    for k, u in enumerate(inputs):
        a, b = edges[k], edges[k + 1]
        solution = solve_ivp(
            lambda t, y, u=u: rhs(y, u), (a, b), x, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True
        )
        inside = (t_eval >= a - 1e-12) & (t_eval <= b + 1e-12)
        out[inside] = solution.sol(np.clip(t_eval[inside], a, b)).T
        x = solution.y[:, -1]
    return out


DCMOTOR = {"R": 1.0, "L": 2.5e-3, "K": 0.1, "J": 0.01, "b": 1e-4}


def dcmotor_exact(
    x0: Sequence[float], edges: Sequence[float], inputs: Sequence[tuple[float, float]], t_eval: np.ndarray
) -> np.ndarray:
    """[current, omega] from the matrix exponential of [[A, B], [0, 0]], inputs held on each segment."""
    R, L, K, J, b = (DCMOTOR[k] for k in ("R", "L", "K", "J", "b"))
    augmented = np.zeros((4, 4))
    augmented[:2, :2] = [[-R / L, -K / L], [K / J, -b / J]]
    augmented[:2, 2:] = [[1.0 / L, 0.0], [0.0, -1.0 / J]]
    out = np.full((len(t_eval), 2), np.nan)
    x = np.asarray(x0, dtype=float)
    for k, u in enumerate(inputs):
        a, c = edges[k], edges[k + 1]
        for i in np.flatnonzero((t_eval >= a - 1e-12) & (t_eval <= c + 1e-12)):
            out[i] = expm(augmented * (t_eval[i] - a))[:2] @ np.concatenate([x, u])
        x = expm(augmented * (c - a))[:2] @ np.concatenate([x, u])
    return out


def bounce_times(h0: float = 1.0, g: float = 9.81, e: float = 0.7, v_min: float = 0.1) -> list[float]:
    """Contact times of the ball: impact speed = previous rebound speed; rests once rebound <= v_min."""
    t = np.sqrt(2.0 * h0 / g)
    v = g * t
    times = [t]
    while (v := e * v) > v_min:
        t += 2.0 * v / g
        times.append(t)
    return times


def ball_state(
    t: float, h0: float = 1.0, g: float = 9.81, e: float = 0.7, v_min: float = 0.1
) -> tuple[float, float]:
    times = bounce_times(h0, g, e, v_min)
    if t < times[0]:
        return h0 - 0.5 * g * t**2, -g * t
    k = int(np.searchsorted(times, t, side="right")) - 1
    if k == len(times) - 1:
        return 0.0, 0.0
    rebound = g * times[0] * e ** (k + 1)
    dt = t - times[k]
    return rebound * dt - 0.5 * g * dt**2, rebound - g * dt


# --- archives -----------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS, ids=variant_id)
def test_every_variant_passes_fmpy_validation(fmus: Fmus, variant: tuple[str, str, str]) -> None:
    assert validate_fmu(str(fmus[variant])) == []


@pytest.mark.parametrize("variant", VARIANTS, ids=variant_id)
def test_generated_c_value_references_match_model_description(
    fmus: Fmus, variant: tuple[str, str, str]
) -> None:
    name, version, interface = variant
    with zipfile.ZipFile(fmus[variant]) as archive:
        names = archive.namelist()
        header = archive.read("sources/model_gen.h").decode()
        table = archive.read("sources/model_gen.c").decode()
    binary = ("binaries/x86_64-linux/" if version == "3.0" else "binaries/linux64/") + f"{name}.so"
    assert {"modelDescription.xml", binary, "sources/model.c", "sources/model.json"} <= set(names)
    in_c = {m[0]: int(m[1]) for m in re.findall(r"#define VR_(\w+) (\d+)", header)}
    rows = re.findall(r'\[VR_(\w+)\] = \{\.name = "((?:[^"\\]|\\.)*)"', table)
    c_names = {re.sub(r"\\(.)", r"\1", literal): c_name for c_name, literal in rows}  # C string -> name
    description = read_model_description(str(fmus[variant]))
    assert len(rows) >= len(description.modelVariables)
    for v in description.modelVariables:
        assert in_c[c_names[v.name]] == v.valueReference, v.name
    assert (
        description.coSimulation is not None if interface == "cs" else description.modelExchange is not None
    )
    capabilities = description.coSimulation or description.modelExchange
    if version != "1.0":  # a model with its state in globals cannot save it in an FMU state
        assert capabilities.canGetAndSetFMUstate == (not capabilities.canBeInstantiatedOnlyOncePerProcess)
        assert description.defaultExperiment.stopTime is not None


# --- cart-pole ----------------------------------------------------------------------------------

CARTPOLE_STEP_S = 0.02
CARTPOLE_STOP_S = 2.0


@pytest.fixture(scope="module")
def cartpole_cs_case() -> tuple[np.ndarray, np.ndarray]:
    """A time-varying force table and the reference trajectory with the force held over each step."""
    table_t = np.linspace(0.0, CARTPOLE_STOP_S, 21)
    table_force = 5.0 * np.sin(3.0 * table_t) + 1.0
    signal = input_signal(table_t, force=table_force)
    edges = np.arange(round(CARTPOLE_STOP_S / CARTPOLE_STEP_S) + 1) * CARTPOLE_STEP_S
    held = np.interp(edges[:-1], table_t, table_force)  # CS inputs are sampled at the start of each step
    reference = piecewise_solution(cartpole_derivatives, [0.0, 0.0, 0.1, 0.0], edges, held, edges)
    return signal, reference


@pytest.mark.parametrize("version", ["1.0", "2.0", "3.0"])
def test_cartpole_cs_matches_solve_ivp(
    fmus: Fmus, version: str, cartpole_cs_case: tuple[np.ndarray, np.ndarray]
) -> None:
    signal, reference = cartpole_cs_case
    result = simulate_fmu(
        str(fmus["cartpole", version, "cs"]),
        stop_time=CARTPOLE_STOP_S,
        output_interval=CARTPOLE_STEP_S,
        start_values={"theta0": 0.1},
        input=signal,
        output=list(STATE_NAMES),
    )
    assert len(result) == len(reference)
    assert abs(reference[-1, 2]) > 0.5  # the pole has really fallen: the check covers the nonlinear range
    np.testing.assert_allclose(as_array(result, STATE_NAMES), reference, rtol=0, atol=1e-8)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_cartpole_me_matches_solve_ivp(fmus: Fmus, version: str) -> None:
    # piecewise-constant force: FMPy stops its ME solver at the input discontinuities
    signal = input_signal([0.0, 0.5, 0.5, 1.0, 1.0, 1.5], force=[2.0, 2.0, -3.0, -3.0, 1.0, 1.0])
    result = simulate_fmu(
        str(fmus["cartpole", version, "me"]),
        stop_time=1.5,
        output_interval=0.05,
        relative_tolerance=1e-10,
        start_values={"theta0": 0.1, "theta_dot0": -0.2},
        input=signal,
        output=list(STATE_NAMES),
        fmi_type="ModelExchange",
    )
    reference = piecewise_solution(
        cartpole_derivatives, [0.0, 0.0, 0.1, -0.2], [0.0, 0.5, 1.0, 1.5], [2.0, -3.0, 1.0], result["time"]
    )
    np.testing.assert_allclose(as_array(result, STATE_NAMES), reference, rtol=0, atol=1e-6)


@pytest.mark.parametrize("version", ["1.0", "2.0", "3.0"])
def test_cartpole_rejects_step_sizes_outside_zero_to_one_second(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["cartpole", version, "cs"])
    set_real(slave, "theta0", 0.1)
    initialize(slave)
    for bad in (0.0, -0.01, 1.5):
        with pytest.raises(FMICallException) as excinfo:
            do_step(slave, 0.0, bad)
        assert excinfo.value.status == ERROR
        assert "outside the allowed range 0 < step <= 1 s" in slave.log[-1][2]
        assert slave.log[-1][1] == "logStatusError"
    do_step(slave, 0.0, 1.0)  # the largest allowed step still works and the state was not touched
    expected = piecewise_solution(
        cartpole_derivatives, [0.0, 0.0, 0.1, 0.0], [0.0, 1.0], [0.0], np.array([1.0])
    )
    np.testing.assert_allclose(get_reals(slave, STATE_NAMES), expected[0], atol=1e-8)


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_cartpole_cs_requests_termination_beyond_track_limit(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["cartpole", version, "cs"], logging_on=True)
    set_real(slave, "track_limit", 0.05)
    initialize(slave)
    set_real(slave, "force", 10.0)
    steps = 0
    while not do_step(slave, steps * 0.02, 0.02):
        steps += 1
    x = get_reals(slave, ["x"])[0]
    assert abs(x) > 0.05 and steps < 10
    assert "requesting termination" in slave.messages()
    if isinstance(slave.fmu, FMU2Slave):
        assert slave.fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx((steps + 1) * 0.02)
    with pytest.raises(FMICallException):
        do_step(slave, (steps + 1) * 0.02, 0.02)  # stepping on after the request is an error


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_cartpole_me_terminates_at_the_track_limit(fmus: Fmus, version: str) -> None:
    result = simulate_fmu(
        str(fmus["cartpole", version, "me"]),
        stop_time=2.0,
        output_interval=0.01,
        start_values={"track_limit": 0.2, "force": 5.0},
        fmi_type="ModelExchange",
        relative_tolerance=1e-8,
    )
    assert result["time"][-1] < 1.0
    assert abs(result["x"][-1]) == pytest.approx(0.2, abs=1e-6)


def test_cartpole_uses_out_of_range_force_unchanged_with_a_warning(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["cartpole", "2.0", "cs"], logging_on=True)
    initialize(slave)
    set_real(slave, "force", 20.0)  # beyond the declared max of 10 N: FMPy accepts the Warning status
    assert slave.log[-1][:2] == (1, "logStatusWarning") and "used unchanged" in slave.log[-1][2]
    do_step(slave, 0.0, 0.1)
    expected = piecewise_solution(cartpole_derivatives, [0.0] * 4, [0.0, 0.1], [20.0], np.array([0.1]))
    np.testing.assert_allclose(get_reals(slave, STATE_NAMES), expected[0], atol=1e-9)


def test_fixed_parameter_cannot_change_after_initialization(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["cartpole", "3.0", "cs"])
    initialize(slave)
    with pytest.raises(FMICallException):
        set_real(slave, "m_cart", 2.0)
    assert "fixed parameter m_cart can only be set before initialization ends" in slave.log[-1][2]


def test_invalid_parameter_is_rejected_at_initialization(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["cartpole", "2.0", "cs"])
    set_real(slave, "m_pole", 0.0)
    with pytest.raises(FMICallException):
        initialize(slave)
    assert "m_cart, m_pole and length must be > 0" in slave.messages()


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_fmu_state_restore_replays_the_trajectory_exactly(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["cartpole", version, "cs"])
    set_real(slave, "theta0", 0.05)
    initialize(slave)
    for k in range(10):
        set_real(slave, "force", 3.0)
        do_step(slave, k * 0.02, 0.02)
    state = slave.fmu.getFMUState()

    def run() -> np.ndarray:
        rows = []
        for k in range(10, 40):
            set_real(slave, "force", 4.0 * np.cos(0.3 * k))
            do_step(slave, k * 0.02, 0.02)
            rows.append(get_reals(slave, STATE_NAMES))
        return np.array(rows)

    first = run()
    slave.fmu.setFMUState(state)
    second = run()
    slave.fmu.freeFMUState(state)
    assert np.array_equal(first, second)
    assert not np.array_equal(first[0], first[-1])


# --- DC motor -----------------------------------------------------------------------------------

MOTOR_EDGES = [0.0, 0.5, 0.8, 1.2, 2.0]
MOTOR_INPUTS = [(12.0, 0.0), (24.0, 0.0), (24.0, 0.5), (-6.0, 0.5)]  # (voltage [V], load_torque [N.m])


def motor_signal() -> np.ndarray:
    times, voltage, load = [], [], []
    for k, (u_v, u_l) in enumerate(MOTOR_INPUTS):  # duplicate times mark the jumps for FMPy
        times += [MOTOR_EDGES[k], MOTOR_EDGES[k + 1]]
        voltage += [u_v, u_v]
        load += [u_l, u_l]
    return input_signal(times, voltage=voltage, load_torque=load)


@pytest.mark.parametrize("variant", [("2.0", "cs"), ("3.0", "cs"), ("2.0", "me")], ids="-".join)
def test_dcmotor_matches_matrix_exponential(fmus: Fmus, variant: tuple[str, str]) -> None:
    version, interface = variant
    result = simulate_fmu(
        str(fmus["dcmotor", version, interface]),
        stop_time=2.0,
        output_interval=0.01,
        start_values={"i0": 1.0, "omega0": 10.0},
        input=motor_signal(),
        output=["current", "omega", "torque"],
        relative_tolerance=1e-10,
        fmi_type="CoSimulation" if interface == "cs" else "ModelExchange",
    )
    expected = dcmotor_exact([1.0, 10.0], MOTOR_EDGES, MOTOR_INPUTS, result["time"])
    scale = np.array([24.0, 240.0])  # stall current [A], no-load speed [rad/s] at 24 V
    np.testing.assert_allclose(
        as_array(result, ["current", "omega"]) / scale, expected / scale, rtol=0, atol=1e-7
    )
    np.testing.assert_allclose(result["torque"], DCMOTOR["K"] * result["current"], rtol=1e-12)


def test_dcmotor_defaults_have_the_documented_time_constants(fmus: Fmus) -> None:
    description = read_model_description(str(fmus["dcmotor", "2.0", "cs"]))
    start = {v.name: float(v.start) for v in description.modelVariables if v.causality == "parameter"}
    assert {k: start[k] for k in DCMOTOR} == DCMOTOR
    R, L, K, J, b = (DCMOTOR[k] for k in ("R", "L", "K", "J", "b"))
    fast, slow = sorted(np.linalg.eigvals([[-R / L, -K / L], [K / J, -b / J]]).real)
    assert -1.0 / fast == pytest.approx(2.5e-3, rel=0.01)  # electrical time constant [s]
    assert -1.0 / slow == pytest.approx(0.99, rel=0.01)  # mechanical time constant [s]
    assert K * 24.0 / (R * b + K**2) == pytest.approx(237.6, rel=1e-3)  # no-load speed at 24 V [rad/s]


# --- bouncing ball ------------------------------------------------------------------------------


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_bouncing_ball_me_bounce_times_match_analytic(fmus: Fmus, version: str) -> None:
    result = simulate_fmu(
        str(fmus["bouncing_ball", version, "me"]),
        stop_time=3.0,
        output_interval=0.05,
        relative_tolerance=1e-10,
        fmi_type="ModelExchange",
    )
    jumps = np.flatnonzero(np.diff(result["v"]) > 1e-6)  # v only ever increases at a bounce
    expected = bounce_times()
    assert len(expected) == 11
    np.testing.assert_allclose(result["time"][jumps + 1], expected, rtol=0, atol=1e-6)
    assert result["bounces"][-1] == len(expected)
    assert result["h"][-1] == 0.0 and result["v"][-1] == 0.0  # at rest after the last bounce


def test_bouncing_ball_cs_locates_contacts_analytically(fmus: Fmus) -> None:
    result = simulate_fmu(str(fmus["bouncing_ball", "2.0", "cs"]), stop_time=3.0, output_interval=0.03)
    expected = np.array([ball_state(t) for t in result["time"]])
    np.testing.assert_allclose(as_array(result, ["h", "v"]), expected, rtol=0, atol=1e-9)
    assert result["bounces"][-1] == 11


# --- feedthrough --------------------------------------------------------------------------------


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_feedthrough_outputs_the_input_of_the_last_step(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["feedthrough", version, "cs"])
    fmu, u, y = slave.fmu, [slave.vr["u"]], [slave.vr["y"]]
    set_, get = (fmu.setFloat64, fmu.getFloat64) if version == "3.0" else (fmu.setReal, fmu.getReal)
    if version == "2.0":
        fmu.setupExperiment(startTime=0.0)
    set_(u, [0.25])
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    assert get(y) == [0.25]  # the start value, taken at initialization
    for k in range(5):
        set_(u, [k * 1.5 - 2.0])
        assert get(y) == [0.25 if k == 0 else (k - 1) * 1.5 - 2.0]  # outputs change only at doStep
        fmu.doStep(k * 0.01, 0.01)
        assert get(y) == [k * 1.5 - 2.0]


# --- typed --------------------------------------------------------------------------------------

FMI3_VALUES: dict[str, tuple[str, Any]] = {
    "real": ("Float64", -1.25e-3),
    "float32": ("Float32", float(np.float32(0.1))),
    "int8": ("Int8", -128),
    "uint8": ("UInt8", 255),
    "int16": ("Int16", -32768),
    "uint16": ("UInt16", 65535),
    "integer": ("Int32", -(2**31)),
    "uint32": ("UInt32", 2**32 - 1),
    "int64": ("Int64", -(2**63)),
    "uint64": ("UInt64", 2**64 - 1),
    "boolean": ("Boolean", True),
    "string": ("String", "grüße, FMI"),
    "enum": ("Int64", 3),
}


def test_typed_fmi2_round_trips_every_type(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["typed", "2.0", "cs"])
    fmu, vr = slave.fmu, slave.vr
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([vr["real_param"]], [2.5])
    fmu.setInteger([vr["integer_param"], vr["enum_param"]], [-9, 3])
    fmu.setBoolean([vr["boolean_param"]], [False])
    fmu.setString([vr["string_param"]], ["changed"])
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.setReal([vr["real_in"]], [1.25])
    fmu.setInteger([vr["integer_in"], vr["enum_in"]], [-7, 3])
    fmu.setBoolean([vr["boolean_in"]], [True])
    buffer = ctypes.create_string_buffer("héllo".encode())
    strings = (ctypes.c_char_p * 1)(ctypes.cast(buffer, ctypes.c_char_p))
    fmu.fmi2SetString(fmu.component, (ctypes.c_uint * 1)(vr["string_in"]), 1, strings)
    buffer.value = b"xxxxx"  # the FMU copied the string into memory it owns
    assert fmu.getReal([vr["real_out"]]) == [0.0]  # outputs change only at doStep
    fmu.doStep(0.0, 0.1)
    assert fmu.getReal([vr["real_out"], vr["real_scaled"], vr["real_integral"]]) == pytest.approx(
        [1.25, 2.5, 0.125]
    )
    assert fmu.getInteger([vr["integer_out"], vr["enum_out"], vr["counter"]]) == [-7, 3, 1]
    assert fmu.getBoolean([vr["boolean_out"]]) == [True]
    assert [s.decode() for s in fmu.getString([vr["string_in"], vr["string_out"]])] == ["héllo", "héllo"]
    assert fmu.getReal([vr["real_param"], vr["pi"]]) == [2.5, np.pi]
    assert fmu.getInteger([vr["integer_param"], vr["enum_param"]]) == [-9, 3]
    assert fmu.getBoolean([vr["boolean_param"]]) == [False]
    assert fmu.getString([vr["string_param"]]) == [b"changed"]
    fmu.setReal([vr["gain"]], [3.0])  # tunable: allowed in step mode, the calculated parameter follows
    assert fmu.getReal([vr["double_gain"]]) == [6.0]
    fmu.doStep(0.1, 0.1)
    assert fmu.getReal([vr["real_scaled"], vr["real_integral"]]) == pytest.approx([3.75, 0.25])
    with pytest.raises(FMICallException):
        fmu.setInteger([vr["enum_in"]], [4])  # not an item of Mode
    assert "enum_in = 4 is not an item of its enumeration type (items 1..3)" in slave.log[-1][2]
    with pytest.raises(FMICallException):
        fmu.getReal([vr["integer_out"]])
    assert "its type is Integer" in slave.log[-1][2]


def test_typed_fmi3_round_trips_every_type(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["typed", "3.0", "cs"])
    fmu, vr = slave.fmu, slave.vr
    initialize(slave)
    for stem, (type_name, value) in FMI3_VALUES.items():
        getattr(fmu, f"set{type_name}")([vr[f"{stem}_in"]], [value])
    fmu.doStep(0.0, 0.5)
    for stem, (type_name, value) in FMI3_VALUES.items():
        got = getattr(fmu, f"get{type_name}")([vr[f"{stem}_out"], vr[f"{stem}_in"]])
        assert got == [value, value], stem
    assert fmu.getFloat64([vr["real_integral"], vr["real_scaled"]]) == pytest.approx([-6.25e-4, -2.5e-3])
    assert fmu.getInt32([vr["counter"]]) == [1]
    with pytest.raises(FMICallException):
        fmu.getInt32([vr["uint32_out"]])
    with pytest.raises(FMICallException):
        fmu.setFloat64([vr["real_out"]], [1.0])
    assert "real_out (value reference 14) is an output and cannot be set" in slave.log[-1][2]
    values = (fmi3ValueReference * 1)(vr["real_in"])
    with pytest.raises(FMICallException):
        fmu.fmi3GetFloat64(fmu.component, values, 1, (ctypes.c_double * 2)(), 2)  # two values for one scalar


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_typed_fail_at_step_returns_error_and_logs_why(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["typed", version, "cs"])
    initialize(slave)
    setter = slave.fmu.setInt32 if version == "3.0" else slave.fmu.setInteger
    setter([slave.vr["fail_at_step"]], [3])
    do_step(slave, 0.0, 0.1)
    do_step(slave, 0.1, 0.1)
    with pytest.raises(FMICallException) as excinfo:
        do_step(slave, 0.2, 0.1)
    assert excinfo.value.status == ERROR
    status, category, message = slave.log[-1]
    assert (status, category) == (ERROR, "logStatusError") and "fail_at_step reached" in message


@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_typed_requests_termination_beyond_terminate_at_time(
    fmus: Fmus, open_slave: OpenSlave, version: str
) -> None:
    slave = open_slave(fmus["typed", version, "cs"])
    set_real(slave, "terminate_at_time", 0.25)
    initialize(slave)
    assert [do_step(slave, k * 0.1, 0.1) for k in range(3)] == [False, False, True]
    if version == "2.0":
        assert slave.fmu.getRealStatus(fmi2LastSuccessfulTime) == pytest.approx(0.3)


def test_typed_fmu_state_restores_strings(fmus: Fmus, open_slave: OpenSlave) -> None:
    slave = open_slave(fmus["typed", "3.0", "cs"])
    fmu, vr = slave.fmu, slave.vr
    initialize(slave)
    fmu.setString([vr["string_in"]], ["before"])
    fmu.doStep(0.0, 0.1)
    state = fmu.getFMUState()
    fmu.setString([vr["string_in"]], ["after"])
    fmu.doStep(0.1, 0.1)
    assert fmu.getString([vr["string_out"]]) == ["after"]
    fmu.setFMUState(state)
    fmu.freeFMUState(state)
    assert fmu.getString([vr["string_in"], vr["string_out"]]) == ["before", "before"]
    assert fmu.getInt32([vr["counter"]]) == [1]


# --- build API ----------------------------------------------------------------------------------


def test_model_names_and_variants() -> None:
    assert models.model_names() == [
        "bouncing_ball",
        "cartpole",
        "dcmotor",
        "feedthrough",
        "gearload",
        "global_state",
        "modelica_names",
        "motor_gearload",
        "pi_controller",
        "slow_init",
        "slow_init_late",
        "slow_plant",
        "stair",
        "typed",
        "typed3",
        "vehicle",
    ]
    by_model: dict[str, set[tuple[str, str]]] = {}
    for v in models.list_variants():
        by_model.setdefault(v.name, set()).add((v.fmi_version, v.interface))
        assert v.description
    assert by_model["cartpole"] == {(v, i) for v in ("1.0", "2.0", "3.0") for i in ("cs", "me")}
    assert by_model["dcmotor"] == {("2.0", "cs"), ("3.0", "cs"), ("2.0", "me")}
    assert by_model["bouncing_ball"] == {("2.0", "me"), ("3.0", "me"), ("2.0", "cs")}
    assert by_model["typed"] == {("2.0", "cs"), ("3.0", "cs")}
    assert by_model["typed3"] == {("3.0", "cs")}
    assert by_model["stair"] == {(v, i) for v in ("1.0", "2.0", "3.0") for i in ("cs", "me")}
    assert by_model["gearload"] == {("2.0", "cs"), ("3.0", "cs"), ("2.0", "me")}
    assert by_model["pi_controller"] == {("2.0", "cs"), ("3.0", "cs")}
    assert by_model["motor_gearload"] == {("2.0", "cs")}
    assert by_model["vehicle"] == {(v, i) for v in ("2.0", "3.0") for i in ("cs", "me")}
    assert by_model["global_state"] == {("2.0", "cs")}
    assert by_model["modelica_names"] == {("2.0", "cs"), ("2.0", "me"), ("3.0", "cs")}
    assert by_model["feedthrough"] == {("2.0", "cs"), ("3.0", "cs")}
    assert by_model["slow_init"] == {(v, i) for v in ("2.0", "3.0") for i in ("cs", "me")}
    assert by_model["slow_init_late"] == {("2.0", "cs"), ("3.0", "me")}
    assert by_model["slow_plant"] == {("2.0", "cs"), ("3.0", "cs")}


def test_unknown_model_or_variant_lists_what_exists() -> None:
    names = "bouncing_ball, cartpole, dcmotor, feedthrough, gearload, global_state, modelica_names, "
    names += "motor_gearload, "
    names += "pi_controller, slow_init, slow_init_late, slow_plant, stair, typed, typed3, vehicle"
    with pytest.raises(ConfigError, match=f"available: {names}"):
        models.example_fmu("pendulum")
    with pytest.raises(ConfigError, match=r"available for typed: fmi_version='2.0' interface='cs'"):
        models.example_fmu("typed", "2.0", "me")
    with pytest.raises(ConfigError, match="fmi_version is one of"):
        models.example_fmu("cartpole", "2")


@pytest.fixture
def private_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("FMU_BRIDGE_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache" / "models"


def test_missing_gcc_raises_dependency_missing(
    private_cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    with pytest.raises(DependencyMissing, match="apt-get install gcc"):
        models.example_fmu("typed")


def test_cache_is_reused_and_rebuilds_are_atomic(fmus: Fmus, private_cache: Path) -> None:
    built = fmus["typed", "2.0", "cs"]
    private_cache.mkdir(parents=True)
    shutil.copy2(built, private_cache / built.name)  # same sources, same key: a cache hit, no gcc run
    path = models.example_fmu("typed", "2.0", "cs")
    assert path == private_cache / built.name
    cached = path.stat().st_mtime_ns
    broken: list[str] = []

    def read_while_rebuilding(stop: threading.Event) -> None:
        while not stop.is_set():  # a reader must only ever see a complete archive
            with zipfile.ZipFile(path) as archive:
                if archive.testzip() is not None or "modelDescription.xml" not in archive.namelist():
                    broken.append("incomplete archive")

    stop = threading.Event()
    reader = threading.Thread(target=read_while_rebuilding, args=(stop,))
    reader.start()
    try:
        rebuilt = models.example_fmu("typed", "2.0", "cs", rebuild=True)
    finally:
        stop.set()
        reader.join()
    assert rebuilt == path and not broken
    assert path.stat().st_mtime_ns != cached
    assert validate_fmu(str(path)) == []
    assert sorted(p.name for p in private_cache.iterdir()) == [path.name]  # no temporary leftovers


def test_changed_sources_change_the_cache_key_and_gcc_errors_are_reported(
    private_cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "models"
    shutil.copytree(model_sources.models_root(), root)
    monkeypatch.setattr(model_sources, "models_root", lambda: root)

    def key() -> str:
        return model_build.cache_key(model_sources.load_spec("typed"), "2.0", "cs")

    original = key()
    source = root / "typed" / "model.c"
    source.write_text(source.read_text() + "\n/* a change */\n")
    assert key() != original
    source.write_text(source.read_text() + "\nthis is not C;\n")
    with pytest.raises(BridgeError, match=re.escape("gcc failed to build typed FMI 2.0 CS")) as excinfo:
        models.example_fmu("typed", "2.0", "cs")
    assert "error:" in str(excinfo.value) and "model.c" in str(excinfo.value)
    assert list(private_cache.iterdir()) == []  # a failed build leaves nothing behind


def test_a_model_that_shares_anothers_equations_builds_and_rebuilds_from_that_model_c(
    private_cache: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tmp_path / "models"
    shutil.copytree(model_sources.models_root(), root)
    monkeypatch.setattr(model_sources, "models_root", lambda: root)
    spec = model_sources.load_spec("slow_init_late")
    assert spec.equations == "slow_init" and spec.c_source == root / "slow_init" / "model.c"
    original = model_build.cache_key(spec, "2.0", "cs")
    shared = root / "slow_init" / "model.c"
    with zipfile.ZipFile(models.example_fmu("slow_init_late", "2.0", "cs")) as archive:
        assert archive.read("sources/model.c") == shared.read_bytes()  # the FMU's sources are whole
    shared.write_text(shared.read_text() + "\n/* a change */\n")
    assert model_build.cache_key(model_sources.load_spec("slow_init_late"), "2.0", "cs") != original

    late = root / "slow_init_late" / "model.json"
    text = late.read_text()
    for value, expected in (
        ('"no_such_model"', "equations 'no_such_model': expected the name of another model with a model.c"),
        ("3", "equations 3: expected the name of another model with a model.c"),
    ):
        late.write_text(text.replace('"equations": "slow_init"', f'"equations": {value}'))
        with pytest.raises(BridgeError, match=re.escape(expected)):
            model_sources.load_spec("slow_init_late")
    late.write_text(text)
    shutil.copy(shared, root / "slow_init_late" / "model.c")
    both = "has its own model.c and equations 'slow_init'; keep one"
    with pytest.raises(BridgeError, match=re.escape(both)):
        model_sources.load_spec("slow_init_late")
