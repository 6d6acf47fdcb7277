"""SSP semantics to the letter: transformations and units applied, what is not read refused by name.

The linear transformation and the unit conversion are checked against OSP libcosim
(``libcosimpy``), which reads the same kind of SSP file with its own parser and applies
``LinearTransformation`` itself: the file with units runs here; libcosim runs the same file with
the conversion written as the equivalent ``LinearTransformation`` (libcosim does not convert units).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.errors import ConfigError
from bridge.experiment.config import parse_experiment
from bridge.fmu import read_model_info
from bridge.plant.system.plant import SystemPlant
from tests.conftest import example_fmu
from tests.plant.ssp_semantics import (
    NS,
    component,
    connection,
    connector,
    motor_load,
    osp_dir,
    ssd,
    unit,
    write,
)

NAMES = ["motor.omega", "motor.current", "load.omega", "load.torque"]
H, STEPS = 1e-3, 300
LINEAR_TORQUE = '<ssc:LinearTransformation factor="0.5" offset="0.01"/>'
UNITS = unit("rad/s", rad=1, s=-1) + unit("rpm", factor=2 * math.pi / 60, rad=1, s=-1)


def ours(ssp: Path, tmp_path: Path, **system: Any) -> np.ndarray:
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": NAMES},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}, **system},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        plant.bind([], NAMES)
        rows = [plant.reset({}, None)]
        rows += [plant.step(None) for _ in range(STEPS)]
    return np.array(rows)


def libcosim(ssp: Path) -> np.ndarray:
    """The four outputs after each macro step, libcosim reading ``ssp`` itself."""
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (pip install libcosimpy)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.ERROR)
    return _observe(CosimExecution.from_ssp_file(str(ssp), step_size=round(H * 1e9)))


def _observe(execution: Any) -> np.ndarray:
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    fmus = {"motor": example_fmu("dcmotor", "2.0", "cs"), "load": example_fmu("gearload", "2.0", "cs")}
    refs = {
        n: {v.name: v.value_reference for v in read_model_info(f).variables.values()} for n, f in fmus.items()
    }
    index = {n: execution.slave_index_from_instance_name(n) for n in fmus}
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    rows = []
    for _ in range(STEPS):
        assert execution.step()
        row = []
        for name in NAMES:
            comp, var = name.split(".")
            row += observer.last_real_values(index[comp], [refs[comp][var]])
        rows.append(row)
    return np.array(rows)


def same(a: np.ndarray, b: np.ndarray) -> None:
    for column, name in enumerate(NAMES):
        np.testing.assert_allclose(a[1:, column], b[:, column], rtol=0, atol=1e-9, err_msg=name)


def test_linear_transformation_matches_libcosim(tmp_path: Path) -> None:
    ssp = write(tmp_path / "linear.ssp", motor_load(torque=LINEAR_TORQUE))
    transformed = ours(ssp, tmp_path)
    same(transformed, libcosim(ssp))
    plain = ours(write(tmp_path / "plain.ssp", motor_load()), tmp_path)
    assert np.max(np.abs(transformed[:, 0] - plain[:, 0])) > 1.0  # the transformation does act


def test_unit_conversion_then_transformation_match_libcosim(tmp_path: Path) -> None:
    """rad/s to rpm on the speed (units declared on the connectors), a linear map on the torque."""
    with_units = motor_load(torque=LINEAR_TORQUE, units=UNITS, omega_unit=("rad/s", "rpm"))
    factor = 1 / (2 * math.pi / 60)
    explicit = motor_load(omega=f'<ssc:LinearTransformation factor="{factor!r}"/>', torque=LINEAR_TORQUE)
    converted = ours(write(tmp_path / "units.ssp", with_units), tmp_path)
    same(converted, libcosim(write(tmp_path / "explicit.ssp", explicit)))
    unconverted = ours(write(tmp_path / "linear.ssp", motor_load(torque=LINEAR_TORQUE)), tmp_path)
    assert np.max(np.abs(converted[:, 2] - unconverted[:, 2])) > 1.0


def test_unit_conversion_applies_before_the_linear_transformation(tmp_path: Path) -> None:
    """SSP: ``target = factor * converted + offset``; an offset unit shows the order."""
    units = unit("rad/s", rad=1, s=-1) + unit("shifted", factor=2.0, offset=3.0, rad=1, s=-1)
    ssp = write(
        tmp_path / "order.ssp",
        motor_load(
            omega='<ssc:LinearTransformation factor="10" offset="1"/>',
            units=units,
            omega_unit=("rad/s", "shifted"),
        ),
    )
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": ["motor.omega"]},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        plant.bind([], ["motor.omega"])
        (link,) = [k for k in plant.links if k.target == "load"]
        assert link.convert is not None
        # in SI: 2 * v + 3 = 2.5 rad/s gives v = -0.25 "shifted"; then 10 * v + 1
        assert link.convert(2.5) == pytest.approx(-1.5, abs=1e-15)  # the other order: 11.5
        plant.reset({}, None)
        for _ in range(3):
            (omega,) = plant.step(None)
        u = plant.master._gather("load")
        j = plant.plants["load"].input_names.index("omega_in")
        assert u[j] == pytest.approx(10 * ((omega - 3.0) / 2.0) + 1.0, rel=1e-15) and omega > 0.0


def test_units_of_different_quantities_are_refused(tmp_path: Path) -> None:
    units = unit("rad/s", rad=1, s=-1) + unit("m", m=1)
    ssp = write(tmp_path / "bad.ssp", motor_load(units=units, omega_unit=("rad/s", "m")))
    with pytest.raises(ConfigError) as info:
        ours(ssp, tmp_path)
    message = str(info.value)
    for text in (
        "motor.omega -> load.omega_in",
        "'rad/s'",
        "'m'",
        "different quantities",
        str(ssp),
        "suppressUnitConversion",
    ):
        assert text in message, message


def test_a_unit_without_a_definition_is_a_warning_and_passes_values(tmp_path: Path) -> None:
    """rpm on the load's input, defined nowhere (no ssd:Units): not comparable, so unconverted."""
    ssp = write(tmp_path / "w.ssp", motor_load(omega_unit=("rad/s", "rpm")))
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": NAMES},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        (warning,) = plant.warnings
        plant.bind([], NAMES)
        assert [link.convert for link in plant.links] == [None, None]
    assert "'rad/s'" in warning and "'rpm'" in warning and "no definition" in warning and str(ssp) in warning


def test_suppress_unit_conversion_passes_values_as_they_are(tmp_path: Path) -> None:
    units = unit("rad/s", rad=1, s=-1) + unit("m", m=1)
    text = motor_load(units=units, omega_unit=("rad/s", "m")).replace(
        'endConnector="omega_in"', 'endConnector="omega_in" suppressUnitConversion="true"'
    )
    suppressed = ours(write(tmp_path / "s.ssp", text), tmp_path)
    plain = ours(write(tmp_path / "plain.ssp", motor_load()), tmp_path)
    np.testing.assert_array_equal(suppressed, plain)


def typed_pair(tmp_path: Path, inner: dict[str, str]) -> Path:
    """Two ``typed`` FMUs: a's Boolean, Integer and Enumeration outputs feed b's inputs."""
    typed = example_fmu("typed", "2.0", "cs")
    kinds = {"boolean": "Boolean", "integer": "Integer", "enum": 'Enumeration name="Mode"'}
    a = [connector(f"{k}_out", "output", typ=t) for k, t in kinds.items()]
    b = [connector(f"{k}_in", "input", typ=t) for k, t in kinds.items()]
    elements = [component("a", "resources/typed.fmu", a, {}), component("b", "resources/typed.fmu", b, {})]
    connections = [connection("a", f"{k}_out", "b", f"{k}_in", inner.get(k, "")) for k in kinds]
    return write(tmp_path / "typed.ssp", ssd(elements, connections), {"resources/typed.fmu": typed})


MAPPINGS = {
    "boolean": '<ssc:BooleanMappingTransformation><ssc:MapEntry source="true" target="false"/>'
    '<ssc:MapEntry source="false" target="true"/></ssc:BooleanMappingTransformation>',
    "integer": '<ssc:IntegerMappingTransformation><ssc:MapEntry source="3" target="30"/>'
    '<ssc:MapEntry source="4" target="-4"/></ssc:IntegerMappingTransformation>',
    "enum": '<ssc:EnumerationMappingTransformation><ssc:MapEntry source="low" target="high"/>'
    "</ssc:EnumerationMappingTransformation>",
}
TYPED_IN = ["a.boolean_in", "a.integer_in", "a.enum_in"]
TYPED_OUT = ["b.boolean_out", "b.integer_out", "b.enum_out"]


def typed_run(ssp: Path, tmp_path: Path, inputs: list[float]) -> np.ndarray:
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": 0.1, "episode_duration": 1.0},
        "actions": {
            "inputs": TYPED_IN,
            "low": dict.fromkeys(TYPED_IN, 0),
            "high": dict.fromkeys(TYPED_IN, 9),
        },
        "observations": {"outputs": TYPED_OUT},
        "reward": {"terms": [{"alive": 0.0}]},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        plant.bind(TYPED_IN, TYPED_OUT)
        plant.reset({}, inputs)
        plant.step(inputs)  # a copies its inputs to its outputs
        return plant.step(inputs)  # b got them at the exchange and copies them


@pytest.mark.parametrize(
    ("inputs", "expected"),
    [
        ([1.0, 3.0, 2.0], [0.0, 30.0, 3.0]),  # true -> false, 3 -> 30, low (2) -> high (3)
        ([0.0, 4.0, 3.0], [1.0, -4.0, 3.0]),  # false -> true, 4 -> -4, high: not listed, unchanged
        ([1.0, 5.0, 1.0], [0.0, 5.0, 1.0]),  # 5 and off (1) are not listed: unchanged
    ],
)
def test_mapping_transformations_map_booleans_integers_and_enumerations(
    tmp_path: Path, inputs: list[float], expected: list[float]
) -> None:
    np.testing.assert_array_equal(typed_run(typed_pair(tmp_path, MAPPINGS), tmp_path, inputs), expected)
    np.testing.assert_array_equal(typed_run(typed_pair(tmp_path, {}), tmp_path, inputs), inputs)


def refused(tmp_path: Path, text: str, *expected: str, fmus: dict[str, Path] | None = None) -> None:
    ssp = write(tmp_path / "refused.ssp", text, fmus)
    with pytest.raises(ConfigError) as info:
        ours(ssp, tmp_path)
    message = str(info.value)
    for part in (*expected, str(ssp)):
        assert part in message, message


def test_a_transformation_of_the_wrong_type_is_refused(tmp_path: Path) -> None:
    text = motor_load(torque=MAPPINGS["boolean"])
    refused(tmp_path, text, "load.torque -> motor.load_torque", "BooleanMappingTransformation", "Float64")


def test_an_enumeration_item_that_does_not_exist_is_refused(tmp_path: Path) -> None:
    bad = MAPPINGS["enum"].replace('target="high"', 'target="max"')
    ssp = typed_pair(tmp_path, {"enum": bad})
    with pytest.raises(ConfigError, match=r"'max' is not an item of b\.enum_in's enumeration"):
        typed_run(ssp, tmp_path, [0.0, 0.0, 1.0])


SSM = 'xmlns:ssm="http://ssp-standard.org/SSP1/SystemStructureParameterMapping"'
MAPPING = (
    '<ssm:MappingEntry source="inertia" target="J"/>'
    '<ssm:MappingEntry source="half_voltage" target="voltage">'
    '<ssc:LinearTransformation factor="2.0"/></ssm:MappingEntry>'
)


def mapped(entries: str = MAPPING, *, file: bool = False) -> str:
    """The motor's parameters bound under other names (inertia, half_voltage = 6 V) and mapped
    back to J and voltage (x 2), inline or from ``mapping.ssm``."""
    text = motor_load()
    plain = '<ssv:Parameter name="J"><ssv:Real value="0.002"/></ssv:Parameter>'
    plain += '<ssv:Parameter name="voltage"><ssv:Real value="12.0"/></ssv:Parameter>'
    assert plain in text
    renamed = '<ssv:Parameter name="inertia"><ssv:Real value="0.002"/></ssv:Parameter>'
    renamed += '<ssv:Parameter name="half_voltage"><ssv:Real value="6.0"/></ssv:Parameter>'
    inner = f'<ssm:ParameterMapping version="1.0" {SSM}>{entries}</ssm:ParameterMapping>'
    mapping = (
        '<ssd:ParameterMapping source="resources/mapping.ssm"/>'
        if file
        else f"<ssd:ParameterMapping>{inner}</ssd:ParameterMapping>"
    )
    text = text.replace(plain, renamed, 1)
    return text.replace(
        "</ssd:ParameterValues></ssd:ParameterBinding>",
        f"</ssd:ParameterValues>{mapping}</ssd:ParameterBinding>",
        1,
    )


def mapping_file(entries: str = MAPPING) -> str:
    return f'<?xml version="1.0" encoding="UTF-8"?>\n<ssm:ParameterMapping version="1.0" {SSM} xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon">{entries}</ssm:ParameterMapping>\n'


@pytest.mark.parametrize("file", [False, True])
def test_a_parameter_mapping_renames_and_transforms_bound_values(tmp_path: Path, file: bool) -> None:
    """Inline and as an .ssm file: the same trajectory as the values bound directly, bit for bit,
    and libcosim's run of those within 1e-9."""
    ssp = write(tmp_path / "mapped.ssp", mapped(file=file))
    if file:
        import zipfile

        with zipfile.ZipFile(ssp, "a") as archive:
            archive.writestr("resources/mapping.ssm", mapping_file())
    from_mapping = ours(ssp, tmp_path)
    plain = write(tmp_path / "plain.ssp", motor_load())
    np.testing.assert_array_equal(from_mapping, ours(plain, tmp_path))
    same(from_mapping, libcosim(plain))


def test_parameter_mapping_entries_that_cannot_apply_are_refused(tmp_path: Path) -> None:
    typo = MAPPING.replace('source="inertia"', 'source="inertial"')
    refused(tmp_path, mapped(typo), "Component 'motor'", "['inertial'] name no parameter", "half_voltage")
    enum = MAPPING + (
        '<ssm:MappingEntry source="inertia" target="J"><ssc:EnumerationMappingTransformation>'
        '<ssc:MapEntry source="a" target="b"/></ssc:EnumerationMappingTransformation></ssm:MappingEntry>'
    )
    refused(tmp_path, mapped(enum), "EnumerationMappingTransformation is not supported in parameter mappings")
    with_unit = mapped().replace('<ssv:Real value="6.0"/>', '<ssv:Real value="6.0" unit="V"/>')
    refused(tmp_path, with_unit, "half_voltage -> voltage", "'V'", "suppressUnitConversion")


SSB = 'xmlns:ssb="http://ssp-standard.org/SSP1/SystemStructureSignalDictionary"'
PLAIN_CONNECTIONS = connection("motor", "omega", "load", "omega_in") + connection(
    "load", "torque", "motor", "load_torque"
)


def through_bus(*, entries: tuple[str, ...] = ("speed", "torque"), extra: str = "") -> str:
    """The motor and load connected through a signal dictionary "shaft" (reference "bus")."""
    text = motor_load()
    assert PLAIN_CONNECTIONS in text
    routed = "".join(
        connection(*ends)
        for ends in (
            ("motor", "omega", "bus", "speed"),
            ("bus", "speed", "load", "omega_in"),
            ("load", "torque", "bus", "torque"),
            ("bus", "torque", "motor", "load_torque"),
        )
    )
    text = text.replace(PLAIN_CONNECTIONS, routed + extra)
    defined = "".join(f'<ssb:DictionaryEntry name="{e}"><ssc:Real/></ssb:DictionaryEntry>' for e in entries)
    shaft = f'<ssd:SignalDictionary name="shaft">{defined}</ssd:SignalDictionary>'
    dictionaries = f"<ssd:SignalDictionaries>{shaft}</ssd:SignalDictionaries>"
    reference = '<ssd:SignalDictionaryReference name="bus" dictionary="shaft"><ssd:Connectors>'
    reference += connector("speed", "inout") + connector("torque", "inout")
    reference += "</ssd:Connectors></ssd:SignalDictionaryReference>"
    text = text.replace("</ssd:Connections>", f"</ssd:Connections>{dictionaries}")
    text = text.replace("<ssd:Elements>", f"<ssd:Elements>{reference}")
    return text.replace(f"{NS}>", f"{NS} {SSB}>", 1)


def test_signals_through_a_dictionary_equal_direct_connections_and_libcosim(tmp_path: Path) -> None:
    routed = ours(write(tmp_path / "bus.ssp", through_bus()), tmp_path)
    plain = write(tmp_path / "plain.ssp", motor_load())
    np.testing.assert_array_equal(routed, ours(plain, tmp_path))
    same(routed, libcosim(plain))


def test_signal_dictionary_misuse_is_refused(tmp_path: Path) -> None:
    refused(
        tmp_path, through_bus(entries=("speed",)), "'torque' is not an entry of signal dictionary 'shaft'"
    )
    twice = connection("motor", "current", "bus", "speed")
    refused(tmp_path, through_bus(extra=twice), "entry 'speed': 2 connections produce it")
    unknown = through_bus().replace('dictionary="shaft"', 'dictionary="shaf"')
    refused(tmp_path, unknown, "reference 'bus': dictionary 'shaf' is not defined")


def test_a_transformation_to_a_system_connector_is_refused(tmp_path: Path) -> None:
    start = '<ssd:Connection startElement="motor" startConnector="omega" endConnector="speed">'
    outer = f"{start}{LINEAR_TORQUE}</ssd:Connection>"
    refused(
        tmp_path,
        motor_load().replace("</ssd:Connections>", f"{outer}</ssd:Connections>"),
        "system's own connectors",
    )


def test_every_connection_element_of_ssp_reaches_the_description(tmp_path: Path) -> None:
    from bridge.plant.system.ssp import read_ssp

    system = read_ssp(
        write(tmp_path / "u.ssp", motor_load(torque=LINEAR_TORQUE, units=UNITS, omega_unit=("rad/s", "rpm")))
    )
    omega, torque = system.connections
    assert torque.transform is not None and (torque.transform.factor, torque.transform.offset) == (0.5, 0.01)
    assert omega.transform is None
    assert system.components["load"].connector_units == {"omega_in": "rpm"}
    assert system.units["rpm"].base == (0, 0, -1, 0, 0, 0, 0, 1)
    assert system.duration_s == pytest.approx(0.4)
    assert ssd([], []).startswith("<?xml")


def libcosim_osp(osp: Path) -> np.ndarray:
    """libcosim reading the OSP file itself; the outputs after each macro step."""
    pytest.importorskip("libcosimpy", reason="libcosimpy is not installed (pip install libcosimpy)")
    from libcosimpy.CosimExecution import CosimExecution

    return _observe(CosimExecution.from_osp_config_file(str(osp)))


@pytest.mark.parametrize("factor", [None, 0.5])
def test_an_osp_system_structure_equals_its_ssp_and_libcosim(tmp_path: Path, factor: float | None) -> None:
    """The same system as OspSystemStructure.xml and as .ssp: one trajectory, bit for bit, and
    libcosim's reading of the OSP file within 1e-9 (the torque through a LinearTransformation
    function, or connected directly)."""
    osp = osp_dir(tmp_path / "osp", torque_factor=factor)
    torque = f'<ssc:LinearTransformation factor="{factor!r}" offset="0.01"/>' if factor is not None else ""
    from_osp = ours(osp, tmp_path)
    from_ssp = ours(write(tmp_path / "same.ssp", motor_load(torque=torque)), tmp_path)
    np.testing.assert_array_equal(from_osp, from_ssp)
    same(from_osp, libcosim_osp(osp))


def test_osp_elements_not_read_are_refused(tmp_path: Path) -> None:
    group = (
        '<VariableGroupConnection><VariableGroup simulator="motor" name="shaft"/>'
        '<VariableGroup simulator="load" name="shaft"/></VariableGroupConnection>'
    )
    osp = osp_dir(tmp_path / "g", extra=group)
    with pytest.raises(ConfigError, match="VariableGroupConnection is not supported") as info:
        ours(osp, tmp_path)
    assert str(osp) in str(info.value)
    summed = osp_dir(tmp_path / "s", torque_factor=0.5)
    summed.write_text(
        summed.read_text().replace('<LinearTransformation name="gain"', '<Sum name="gain" inputCount="1"')
    )
    with pytest.raises(ConfigError, match="'gain': Sum functions are not supported"):
        ours(summed, tmp_path)


MOTOR_J = '<ssv:Parameter name="J"><ssv:Real value="0.002"/></ssv:Parameter>'
GRAM_M2 = unit("g.m2", factor=1e-3, kg=1, m=2) + unit("kg.m2", kg=1, m=2)


def test_a_bound_value_in_another_unit_is_converted_and_matches_libcosim(tmp_path: Path) -> None:
    """The motor's inertia bound as 2 g.m2 (ssv:Real unit): the run of 0.002 kg.m2, as libcosim
    computes it from the value in the FMU's own unit."""
    text = motor_load(units=GRAM_M2)
    assert MOTOR_J in text
    grams = text.replace(MOTOR_J, MOTOR_J.replace('value="0.002"', 'value="2.0" unit="g.m2"'))
    converted = ours(write(tmp_path / "grams.ssp", grams), tmp_path)
    same(converted, libcosim(write(tmp_path / "si.ssp", motor_load())))
    from bridge.plant.system.ssp import read_ssp

    assert read_ssp(tmp_path / "grams.ssp").components["motor"].parameters["J"] == pytest.approx(
        0.002, rel=1e-15
    )


def test_a_bound_value_of_another_quantity_is_refused(tmp_path: Path) -> None:
    text = motor_load(units=GRAM_M2 + unit("m", m=1))
    bad = text.replace(MOTOR_J, MOTOR_J.replace('value="0.002"', 'value="2.0" unit="m"'))
    refused(
        tmp_path, bad, "component 'motor': parameter binding 'J'", "'m'", "'kg.m2'", "different quantities"
    )


def nested_text() -> str:
    """The load inside a nested system "drive" whose connectors w_in and t_out carry the speed in
    and the torque out; the motor at the top."""
    flat = motor_load()
    load_start = flat.index('<ssd:Component name="load"')
    load_end = flat.index("</ssd:Component>", load_start) + len("</ssd:Component>")
    load = flat[load_start:load_end]
    inner = connection("", "w_in", "load", "omega_in") + connection("load", "torque", "", "t_out")
    inner = inner.replace('startElement="" ', "").replace('endElement="" ', "")
    drive = (
        '<ssd:System name="drive"><ssd:Connectors>'
        + connector("w_in", "input")
        + connector("t_out", "output")
        + f"</ssd:Connectors><ssd:Elements>{load}</ssd:Elements><ssd:Connections>{inner}</ssd:Connections>"
        "</ssd:System>"
    )
    outer = connection("motor", "omega", "drive", "w_in") + connection(
        "drive", "t_out", "motor", "load_torque"
    )
    text = flat.replace(load, drive).replace(PLAIN_CONNECTIONS, outer)
    assert 'startElement="load"' in text and "drive" in text
    return text


def test_a_nested_system_runs_as_its_flat_equivalent_and_libcosim(tmp_path: Path) -> None:
    """Components of a nested system are named system/component; the same trajectory as the flat
    system bit for bit, and libcosim's run of the flat one within 1e-9."""
    ssp = write(tmp_path / "nested.ssp", nested_text())
    names = ["motor.omega", "motor.current", "drive/load.omega", "drive/load.torque"]
    data: dict[str, Any] = {
        "model": {"fmu": str(ssp), "step_size": H, "episode_duration": 1.0},
        "observations": {"outputs": names},
        "reward": {"terms": [{"alive": 0.0}]},
        "system": {"components": {"motor": {"feedthrough": False}}},
    }
    with SystemPlant(parse_experiment(data, source=tmp_path / "e.yaml")) as plant:
        assert sorted(plant.system.components) == ["drive/load", "motor"]
        plant.bind([], names)
        nested = np.array([plant.reset({}, None)] + [plant.step(None) for _ in range(STEPS)])
    plain = write(tmp_path / "plain.ssp", motor_load())
    np.testing.assert_array_equal(nested, ours(plain, tmp_path))
    same(nested, libcosim(plain))
