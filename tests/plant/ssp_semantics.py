"""SSP 1.0 files with units, transformations and the elements a reader must refuse (hand-written)."""

from __future__ import annotations

import zipfile
from pathlib import Path

from tests.conftest import example_fmu

NS = (
    'xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" '
    'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
    'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues"'
)
MOTOR = {"J": 0.002, "voltage": 12.0}
LOAD = {"N": 5.0, "k": 50.0, "d": 0.5, "J": 0.05}


def connector(name: str, kind: str, unit: str = "", typ: str = "Real") -> str:
    attribute = f' unit="{unit}"' if unit else ""
    return f'<ssd:Connector name="{name}" kind="{kind}"><ssc:{typ}{attribute}/></ssd:Connector>'


def component(
    name: str, source: str, connectors: list[str], parameters: dict[str, float], extra: str = ""
) -> str:
    values = "".join(
        f'<ssv:Parameter name="{k}"><ssv:Real value="{v!r}"/></ssv:Parameter>' for k, v in parameters.items()
    )
    bindings = (
        "<ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>"
        f'<ssv:ParameterSet version="1.0" name="p"><ssv:Parameters>{values}</ssv:Parameters>'
        "</ssv:ParameterSet></ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>"
        if parameters
        else ""
    )
    return (
        f'<ssd:Component name="{name}" source="{source}"><ssd:Connectors>{"".join(connectors)}'
        f"</ssd:Connectors>{bindings}{extra}</ssd:Component>"
    )


def connection(a: str, y: str, b: str, u: str, inner: str = "", *, attributes: str = "") -> str:
    return (
        f'<ssd:Connection startElement="{a}" startConnector="{y}" endElement="{b}" endConnector="{u}"'
        f"{attributes}>{inner}</ssd:Connection>"
    )


def ssd(
    elements: list[str], connections: list[str], units: str = "", system_extra: str = "", step: float = 1e-3
) -> str:
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<ssd:SystemStructureDescription version="1.0" name="s" {NS}>'
        f'<ssd:System name="s"><ssd:Elements>{"".join(elements)}</ssd:Elements>'
        f"<ssd:Connections>{''.join(connections)}</ssd:Connections>{system_extra}</ssd:System>"
        f"{units}"
        f'<ssd:DefaultExperiment startTime="0" stopTime="0.4"><ssd:Annotations>'
        f'<ssc:Annotation type="org.example"><x stepSize="{step!r}"/></ssc:Annotation>'
        "</ssd:Annotations></ssd:DefaultExperiment></ssd:SystemStructureDescription>\n"
    )


def unit(name: str, factor: float = 1.0, offset: float = 0.0, **base: int) -> str:
    exponents = " ".join(f'{k}="{v}"' for k, v in base.items())
    base_unit = f'<ssc:BaseUnit {exponents} factor="{factor!r}" offset="{offset!r}"/>'
    return f'<ssc:Unit name="{name}">{base_unit}</ssc:Unit>'


def motor_load(
    omega: str = "", torque: str = "", units: str = "", omega_unit: tuple[str, str] = ("", "")
) -> str:
    """The motor and gearbox load, ``omega``/``torque``: what the two connections hold inside."""
    elements = [
        component(
            "motor",
            "resources/dcmotor.fmu",
            [
                connector("load_torque", "input"),
                connector("omega", "output", omega_unit[0]),
                connector("current", "output"),
            ],
            MOTOR,
        ),
        component(
            "load",
            "resources/gearload.fmu",
            [
                connector("omega_in", "input", omega_unit[1]),
                connector("torque", "output"),
                connector("omega", "output"),
            ],
            LOAD,
        ),
    ]
    connections = [
        connection("motor", "omega", "load", "omega_in", omega),
        connection("load", "torque", "motor", "load_torque", torque),
    ]
    return ssd(elements, connections, f"<ssd:Units>{units}</ssd:Units>" if units else "")


def write(path: Path, text: str, fmus: dict[str, Path] | None = None) -> Path:
    """An .ssp archive with ``SystemStructure.ssd`` and the FMUs (default: the motor and load)."""
    fmus = fmus or {
        "resources/dcmotor.fmu": example_fmu("dcmotor", "2.0", "cs"),
        "resources/gearload.fmu": example_fmu("gearload", "2.0", "cs"),
    }
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", text)
        for name, fmu in fmus.items():
            archive.write(fmu, name)
    return path


def osp_dir(directory: Path, *, torque_factor: float | None = None, extra: str = "") -> Path:
    """The motor and load as OSP's ``OspSystemStructure.xml`` with the FMUs beside it; the torque
    through a LinearTransformation function when ``torque_factor`` is given (offset 0.01)."""
    import shutil

    directory.mkdir(parents=True, exist_ok=True)
    shutil.copy(example_fmu("dcmotor", "2.0", "cs"), directory / "dcmotor.fmu")
    shutil.copy(example_fmu("gearload", "2.0", "cs"), directory / "gearload.fmu")

    def initial(values: dict[str, float]) -> str:
        inner = "".join(
            f'<InitialValue variable="{k}"><Real value="{v!r}"/></InitialValue>' for k, v in values.items()
        )
        return f"<InitialValues>{inner}</InitialValues>"

    def variable(simulator: str, name: str) -> str:
        return f'<Variable simulator="{simulator}" name="{name}"/>'

    def signal(end: str, simulator: str, name: str) -> str:
        inner = f'<Signal function="gain" name="{end}"/>{variable(simulator, name)}'
        return f"<SignalConnection>{inner}</SignalConnection>"

    torque = (
        signal("in", "load", "torque") + signal("out", "motor", "load_torque")
        if torque_factor is not None
        else f"<VariableConnection>{variable('motor', 'load_torque')}{variable('load', 'torque')}"
        "</VariableConnection>"
    )
    functions = (
        f'<Functions><LinearTransformation name="gain" factor="{torque_factor!r}" offset="0.01"/></Functions>'
        if torque_factor is not None
        else ""
    )
    text = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<OspSystemStructure xmlns="http://opensimulationplatform.com/MSMI/OSPSystemStructure" version="0.1">'
        "<StartTime>0.0</StartTime><BaseStepSize>0.001</BaseStepSize><Algorithm>fixedStep</Algorithm>"
        f'<Simulators><Simulator name="motor" source="dcmotor.fmu">{initial(MOTOR)}</Simulator>'
        f'<Simulator name="load" source="gearload.fmu">{initial(LOAD)}</Simulator></Simulators>'
        f"{functions}<Connections>"
        f"<VariableConnection>{variable('motor', 'omega')}{variable('load', 'omega_in')}</VariableConnection>"
        f"{torque}{extra}</Connections></OspSystemStructure>\n"
    )
    path = directory / "OspSystemStructure.xml"
    path.write_text(text)
    return path
