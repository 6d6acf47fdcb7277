"""The native master carries Integer, Boolean, Enumeration (and FMI 3.0's other numeric types) as
the Python master does, bit for bit, refuses the same values with the same words, and fails as it
does: a component's failed step, a non-finite value on a link, a failure inside an iteration."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.experiment.config import parse_experiment
from bridge.plant.system.native_master import python_master_reason
from bridge.plant.system.plant import SystemPlant

# typed copies each input to its output at the end of each doStep
TYPES2 = {"real": "real", "integer": "integer", "boolean": "boolean", "enum": "enum"}
TYPES3 = {
    **TYPES2,
    **{t: t for t in ("float32", "int8", "uint8", "int16", "uint16", "uint32", "int64", "uint64")},
}


def typed_chain(
    tmp_path: Path,
    version: str,
    *,
    extra: list[str] = (),
    system: dict[str, Any] | None = None,
    **params: Any,
) -> tuple[Any, list[str], list[str]]:
    """a -> b, every numeric type of the FMI version linked output to input, and an Int32 feeding
    a Float64 (``a.integer_out -> c.real_in``); the task drives a's inputs, observes b's and c's
    outputs, b's step counter and b's connected Boolean input."""
    types = TYPES2 if version == "2.0" else TYPES3
    fmu = f"example:typed:{version}"
    components = {
        "a": {"fmu": fmu},
        "b": {"fmu": fmu, "parameters": params.get("b", {})},
        "c": {"fmu": fmu},
    }
    if "a" in params:
        components["a"]["parameters"] = params["a"]
    connections = [f"a.{t}_out -> b.{t}_in" for t in types] + ["a.integer_out -> c.real_in"]
    inputs = [f"a.{t}_in" for t in types]
    outputs = [f"b.{t}_out" for t in types] + ["c.real_out", "b.counter", "b.boolean_in"]
    data = {
        "model": {"step_size": 0.1, "episode_duration": 100.0},
        "system": {"components": components, "connections": connections, **(system or {})},
        "observations": {"outputs": outputs},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=tmp_path / "typed.yaml"), inputs, outputs


def values(names: list[str], i: int) -> list[float]:
    """Inputs for sample ``i``, each within its type and varying from sample to sample."""
    per = {
        "real": np.sin(0.3 * i) * 1e3,
        "integer": (i * 7919) % 4001 - 2000,
        "boolean": i % 2,
        "enum": 1 + i % 3,
        "float32": np.cos(0.7 * i) * 123.456789,
        "int8": (i * 37) % 256 - 128,
        "uint8": (i * 53) % 256,
        "int16": (i * 7919) % 65536 - 32768,
        "uint16": (i * 7919) % 65536,
        "uint32": (i * 104729 * 7919) % 2**32,
        "int64": -(2**62) + i * 2**40,
        "uint64": 2**63 + i * 2**41,
    }
    return [float(per[n.split(".")[1].removesuffix("_in")]) for n in names]


def run(
    exp: Any, inputs: list[str], outputs: list[str], samples: int = 12
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The observations of ``samples`` samples, then every component's every output (the
    recording's values) as one more row; and whether the native master ran."""
    with SystemPlant(exp) as plant:
        plant.bind(inputs, outputs)
        rows = [plant.reset({}, values(inputs, 0))]
        rows += [plant.step(values(inputs, i)) for i in range(1, samples)]
        recorded = [v for outs in plant.component_outputs().values() for v in outs.values()]
        return np.array(rows), np.array(recorded), plant.master.native is not None


@pytest.mark.parametrize("iterations", [1, 3])
@pytest.mark.parametrize("algorithm", ["jacobi", "gauss_seidel"])
@pytest.mark.parametrize("version", ["2.0", "3.0"])
def test_typed_links_run_natively_and_equal_the_python_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, version: str, algorithm: str, iterations: int
) -> None:
    """Before: any non-Float64 connection selected the Python master."""
    system = {
        "algorithm": algorithm,
        **({"iteration": {"max_iterations": iterations}} if iterations > 1 else {}),
    }
    exp, inputs, outputs = typed_chain(tmp_path, version, system=system)
    native, recorded, used = run(exp, inputs, outputs)
    assert used
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python, python_recorded, used = run(exp, inputs, outputs)
    assert not used
    np.testing.assert_array_equal(native, python)
    np.testing.assert_array_equal(recorded, python_recorded)
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE", "1")  # the Python master over Python FMI calls
    np.testing.assert_array_equal(native, run(exp, inputs, outputs)[0])
    # the values arrived, typed: a copies its inputs at the end of its step; under Jacobi b takes
    # a's outputs of t (one sample late), under Gauss-Seidel or iterated those of t + H
    lag = 1 if algorithm == "jacobi" and iterations == 1 else 0
    for i in range(lag + 1, 12):
        expected = values(inputs, i - lag)
        got = native[i, : len(inputs)]
        if version == "3.0":  # Float32 rounds
            position = inputs.index("a.float32_in")
            expected[position] = float(np.float32(expected[position]))
        np.testing.assert_array_equal(got, expected)
    assert native[5, len(inputs) + 1] == 5  # b's counter


@pytest.mark.parametrize(
    ("name", "value", "words"),
    [
        ("a.integer_in", 2.5, "expected whole numbers in range"),
        ("a.boolean_in", 2.0, "expected 0 or 1"),
        ("a.enum_in", 4.0, "items:"),
        ("a.integer_in", 2.0**31, "whole numbers in range"),
    ],
)
def test_a_value_its_type_refuses_is_refused_as_in_python(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, name: str, value: float, words: str
) -> None:
    exp, inputs, outputs = typed_chain(tmp_path, "2.0")

    def fail() -> str:
        bad = values(inputs, 1)
        bad[inputs.index(name)] = value
        with SystemPlant(exp) as plant:
            plant.bind(inputs, outputs)
            plant.reset({}, values(inputs, 0))
            plant.step(values(inputs, 1))
            with pytest.raises(Exception) as info:
                plant.step(bad)
            return f"{type(info.value).__name__}: {info.value} @ {plant.time_s} {plant.sample}"

    native = fail()
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    assert native == fail()
    assert words in native and name.split(".")[1] in native


@pytest.mark.parametrize(
    "system",
    [{}, {"algorithm": "gauss_seidel"}, {"iteration": {"max_iterations": 3}}],
    ids=["jacobi", "gauss-seidel", "mid-iteration"],
)
def test_an_integer_out_of_range_on_a_link_is_refused_as_in_python(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, system: dict[str, Any]
) -> None:
    """Int32 -> Int8 is allowed (integers feed integers); 300 on the link is not an Int8. Iterated,
    the first pass gives b the 5 of t and the second the 300 of t + H: refused in the middle of the
    iteration, with every FMU state saved and a stepped in that pass."""
    inputs_, outputs_ = ["a.integer_in"], ["b.int8_out"]
    link = parse_experiment(
        {
            "model": {"step_size": 0.1, "episode_duration": 10.0},
            "system": {
                "components": {"a": {"fmu": "example:typed:3.0"}, "b": {"fmu": "example:typed:3.0"}},
                "connections": ["a.integer_out -> b.int8_in"],
                **system,
            },
            "observations": {"outputs": outputs_},
            "reward": {"terms": [{"alive": 0.0}]},
        },
        source=tmp_path / "link.yaml",
    )

    def fail() -> tuple[str, list[Any], Any, bool]:
        rows: list[Any] = []
        with SystemPlant(link) as plant:
            plant.bind(inputs_, outputs_)
            rows.append(plant.reset({}, [5.0]).tolist())
            with pytest.raises(Exception) as info:
                for value in (7.0, 300.0, 1.0, 1.0):  # a copies 300 at the end of its step
                    rows.append(plant.step([value]).tolist())
            counters = {n: (p.model.step_index, p.sample) for n, p in plant.plants.items()}  # type: ignore[attr-defined]
            where = (plant.time_s, plant.sample, counters)
            return f"{type(info.value).__name__}: {info.value}", rows, where, plant.master.native is not None

    native = fail()
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python = fail()
    assert native[3] and not python[3]
    assert native[:3] == python[:3]
    assert len(native[1]) == (3 if system == {} else 2)  # Jacobi alone passes the 300 one step late
    assert "int8_in=300" in native[0] and "range [-128, 127]" in native[0], native[0]


def failing(tmp_path: Path, **system: Any) -> Any:
    """Two typed components: b fails its 7th doStep (fail_at_step), or its input is infinite."""
    data = {
        "model": {"step_size": 0.1, "sampling_time": system.pop("sampling", 0.1), "episode_duration": 100.0},
        "system": {
            "components": {
                "a": {"fmu": "example:typed:2.0", "parameters": system.pop("a", {})},
                "b": {"fmu": "example:typed:2.0", "parameters": system.pop("b", {})},
            },
            "connections": ["a.real_scaled -> b.real_in", "a.integer_out -> b.integer_in"][
                : 1 if system.pop("floats_only", False) else 2
            ],
            **system,
        },
        "observations": {"outputs": ["b.real_out", "b.integer_out", "b.counter", "a.counter"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=tmp_path / "failing.yaml")


def until_failure(exp: Any) -> tuple[list[Any], str, Any, bool]:
    """Samples until one fails: the rows before, the error, and where the system stands after."""
    rows: list[Any] = []
    with SystemPlant(exp) as plant:
        plant.bind(["a.real_in", "a.integer_in"], ["b.real_out", "b.integer_out", "b.counter", "a.counter"])
        rows.append(plant.reset({}, [1.0, 1.0]).tolist())
        with pytest.raises(Exception) as info:
            for i in range(100):
                rows.append(plant.step([1.0 + i, float(i)]).tolist())
        after = (plant.time_s, plant.sample, plant.terminated, plant.master.last_iterations)
        steps = {n: (p.model.step_index, p.sample) for n, p in plant.plants.items()}  # type: ignore[attr-defined]
        error = info.value
        return rows, f"{type(error).__name__}: {error}", (after, steps), plant.master.native is not None


@pytest.mark.parametrize(
    "setting",
    [
        {"b": {"fail_at_step": 7}},
        {"b": {"fail_at_step": 7}, "sampling": 0.3},  # within a sample of three macro steps
        {"b": {"fail_at_step": 7}, "algorithm": "gauss_seidel"},
        {"b": {"fail_at_step": 7}, "iteration": {"max_iterations": 3}},  # states saved, then the failure
        {"a": {"gain": 1e308}},  # a's real_scaled overflows to inf at its 2nd step; the link carries it
        {"a": {"gain": 1e308}, "floats_only": True},  # before: a had not stepped on the native master
        {"a": {"gain": 1e308}, "algorithm": "gauss_seidel", "iteration": {"max_iterations": 3}},
    ],
    ids=[
        "step",
        "in-a-sample",
        "gauss-seidel",
        "iteration",
        "inf-on-link",
        "inf-float64",
        "inf-in-iteration",
    ],
)
def test_a_failure_reads_and_keeps_as_on_the_python_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, setting: dict[str, Any]
) -> None:
    """The same error (the FMU's own log included), the same rows before it, the same time, sample
    and step counters after it."""
    native = until_failure(failing(tmp_path, **dict(setting)))
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python = until_failure(failing(tmp_path, **dict(setting)))
    assert native[3] and not python[3]
    assert native[1] == python[1]
    assert native[0] == python[0] and len(native[0]) > 1
    assert native[2] == python[2]
    if "b" in setting:
        assert "fail_at_step reached" in native[1] and "component 'b'" in native[1], native[1]
    else:
        assert "inf" in native[1] and "real_in" in native[1], native[1]


def test_observed_variables_of_every_type_keep_the_native_master_and_its_reason(tmp_path: Path) -> None:
    """Before: python_master_reason looked at connections alone and said "native" while an observed
    Int32 (b.counter) or Boolean input made the system run on the Python master."""
    from bridge.cli.system import summary

    exp, inputs, outputs = typed_chain(tmp_path, "3.0")
    with SystemPlant(exp) as plant:
        plant.bind(inputs, outputs)
        plant.reset({}, values(inputs, 0))
        assert plant.master.native is not None
        assert python_master_reason(plant.system, plant.plants, plant.couplings, plant.infos) is None
        assert summary(plant)["master"]["runs"] == "native"


def test_a_component_with_input_clocks_is_named_as_the_reason(tmp_path: Path) -> None:
    """Its clocks tick in Python: the reason says so, and the choice follows it."""
    data = {
        "model": {"step_size": 0.1, "episode_duration": 1.0},
        "system": {
            "components": {"t": {"fmu": "example:typed:3.0"}, "c": {"fmu": "example:clocks3:3.0"}},
            "connections": [],
        },
        "observations": {"outputs": ["t.real_out"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "clocks.yaml")) as plant:
        reason = python_master_reason(plant.system, plant.plants, plant.couplings, plant.infos)
        plant.bind([], ["t.real_out"])
        plant.reset({}, None)
        assert plant.master.native is None
    assert reason is not None and "'c' has input clocks" in reason, reason


def arrays(tmp_path: Path) -> Any:
    """Two strict_arrays (FMI 3.0 arrays that refuse any get or set of another nValues): an element
    of a's output matrix feeds one element of b's input array, the task drives one element of a's."""
    from bridge.models.strict import strict_arrays_fmu

    fmu = str(strict_arrays_fmu())
    data = {
        "model": {"step_size": 0.1, "episode_duration": 10.0},
        "system": {
            "components": {"a": {"fmu": fmu}, "b": {"fmu": fmu}},
            "connections": ["a.y[1,2] -> b.u[2]", "a.total -> b.u[3]"],
        },
        "observations": {"outputs": ["b.total", "b.y[1,2]"]},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    return parse_experiment(data, source=tmp_path / "arrays.yaml")


def test_arrays_used_in_part_run_natively_and_equal_the_python_master(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Before: an FMI 3.0 array connected or driven in part selected the Python master (the array
    is read, the elements written, and set whole, as the signal group does)."""

    def run_arrays() -> tuple[np.ndarray, bool]:
        with SystemPlant(arrays(tmp_path)) as plant:
            plant.bind(["a.u[1]"], ["b.total", "b.y[1,2]"])
            rows = [plant.reset({}, [1.0])]
            rows += [plant.step([1.0 + np.sin(i)]) for i in range(15)]
            return np.array(rows), plant.master.native is not None

    native, used = run_arrays()
    assert used
    monkeypatch.setenv("FMU_BRIDGE_NO_NATIVE_MASTER", "1")
    python, used = run_arrays()
    assert not used
    np.testing.assert_array_equal(native, python)
    assert np.ptp(native[:, 0]) > 0.1  # the values moved


@pytest.mark.parametrize(
    "observed",
    [["b.real_out"], ["b.counter"], ["b.boolean_out", "b.enum_out"], ["b.real_in", "b.counter"]],
)
def test_the_reason_and_the_choice_agree_whatever_is_observed(tmp_path: Path, observed: list[str]) -> None:
    """Float64 links only; the task observes Float64, Int32, Boolean and Enumeration outputs and a
    connected input. Before: the reason said "native" (it read the connections alone) while the
    choice fell to the Python master for the Int32, Boolean and Enumeration variables bound."""
    data = {
        "model": {"step_size": 0.1, "episode_duration": 10.0},
        "system": {
            "components": {"a": {"fmu": "example:typed:2.0"}, "b": {"fmu": "example:typed:2.0"}},
            "connections": ["a.real_out -> b.real_in"],
        },
        "observations": {"outputs": observed},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "observed.yaml")) as plant:
        reason = python_master_reason(plant.system, plant.plants, plant.couplings, plant.infos)
        plant.bind(["a.real_in"], observed)
        plant.reset({}, [2.0])
        rows = [plant.step([3.0]) for _ in range(3)]
        assert reason is None and plant.master.native is not None
    if observed == ["b.real_out"]:  # a copied its start value 0 at initialisation, then 3 from its first step
        assert [r.tolist() for r in rows] == [[0.0], [3.0], [3.0]]


def test_integer_and_boolean_links_equal_osp_libcosim(tmp_path: Path) -> None:
    """A second, independent engine: libcosim's Jacobi master carries Integer and Boolean values
    as they are (its connect_integer_variables / connect_boolean_variables); the native master gives
    the same b outputs at every macro step, the integral within 1e-14 (typed FMI 2.0: a copies its
    inputs at the end of each step, b copies what a gave it)."""
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (pip install libcosimpy)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    from bridge.fmu import read_model_info
    from bridge.models import example_fmu

    fmu = example_fmu("typed", "2.0", "cs")
    refs = {v.name: v.value_reference for v in read_model_info(fmu).variables.values()}
    start = {"integer_in": 42, "boolean_in": True, "real_in": 1.5}
    links = [("integer_out", "integer_in"), ("boolean_out", "boolean_in"), ("real_scaled", "real_in")]
    steps = 20
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(step_size=round(0.1 * 1e9))
    a = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="a"))
    b = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="b"))
    execution.integer_initial_value(a, refs["integer_in"], 42)
    execution.boolean_initial_value(a, refs["boolean_in"], True)
    execution.real_initial_value(a, refs["real_in"], 1.5)
    if not hasattr(execution, "_CosimExecution__connect_integer_variables"):
        # libcosimpy 0.0.6 binds cosim_execution_connect_integer_variables under another name than
        # the method calls (__connect_int_variables): the same C function, reached by that name
        execution._CosimExecution__connect_integer_variables = (
            execution._CosimExecution__connect_int_variables
        )  # type: ignore[attr-defined]
    execution.connect_integer_variables(a, refs["integer_out"], b, refs["integer_in"])
    execution.connect_boolean_variables(a, refs["boolean_out"], b, refs["boolean_in"])
    execution.connect_real_variables(a, refs["real_scaled"], b, refs["real_in"])
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    reference = []
    for _ in range(steps):
        assert execution.step()
        integers = observer.last_integer_values(b, [refs["integer_out"], refs["counter"]])
        booleans = observer.last_boolean_values(b, [refs["boolean_out"]])
        reals = observer.last_real_values(b, [refs["real_out"], refs["real_integral"]])
        reference.append([*integers, *(float(v) for v in booleans), *reals])
    outputs = ["b.integer_out", "b.counter", "b.boolean_out", "b.real_out", "b.real_integral"]
    data = {
        "model": {"step_size": 0.1, "episode_duration": 10.0},
        "system": {
            "components": {
                "a": {"fmu": "example:typed:2.0", "start_values": start},
                "b": {"fmu": "example:typed:2.0"},
            },
            "connections": [f"a.{y} -> b.{u}" for y, u in links],
        },
        "observations": {"outputs": outputs},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "libcosim.yaml")) as plant:
        plant.bind([], outputs)
        plant.reset({}, None)
        ours = [plant.step(None).tolist() for _ in range(steps)]
        assert plant.master.native is not None
    ours_, reference_ = np.array(ours), np.array(reference, dtype=float)
    np.testing.assert_array_equal(ours_[:, :4], reference_[:, :4])  # Integer, Boolean, the Real copied
    # the integral sums h each step: libcosim's h is 10^8 ns, ours 0.1 s, apart in the last bits
    np.testing.assert_allclose(ours_[:, 4], reference_[:, 4], rtol=1e-14, atol=0)
    assert ours[-1][:3] == [42.0, 20.0, 1.0] and ours[-1][3] == 3.0  # gain 2 * 1.5
