"""Writes SSP 1.0 archives for the system tests (the schema's elements, written by hand)."""

from __future__ import annotations

import zipfile
from pathlib import Path

HEAD = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<ssd:SystemStructureDescription version="1.0" name="{name}"\n'
    '  xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"\n'
    '  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"\n'
    '  xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">\n'
    '  <ssd:System name="{name}">\n    <ssd:Elements>\n'
)


def ssd_text(
    components: dict[str, tuple[str, dict[str, str], dict[str, float]]],
    connections: list[tuple[str, str, str, str]],
    name: str = "system",
) -> str:
    """``components``: name -> (source, {connector: kind}, {parameter: value})."""
    out = [HEAD.format(name=name)]
    for comp, (source, connectors, parameters) in components.items():
        out.append(f'      <ssd:Component name="{comp}" source="{source}">\n        <ssd:Connectors>\n')
        for connector, kind in connectors.items():
            out.append(
                f'          <ssd:Connector name="{connector}" kind="{kind}"><ssc:Real/></ssd:Connector>\n'
            )
        out.append("        </ssd:Connectors>\n")
        if parameters:
            out.append(
                "        <ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues>"
                '<ssv:ParameterSet version="1.0" name="p"><ssv:Parameters>\n'
            )
            for key, value in parameters.items():
                out.append(
                    f'          <ssv:Parameter name="{key}"><ssv:Real value="{value!r}"/></ssv:Parameter>\n'
                )
            out.append(
                "        </ssv:Parameters></ssv:ParameterSet></ssd:ParameterValues>"
                "</ssd:ParameterBinding></ssd:ParameterBindings>\n"
            )
        out.append("      </ssd:Component>\n")
    out.append("    </ssd:Elements>\n    <ssd:Connections>\n")
    for a, y, b, u in connections:
        out.append(
            f'      <ssd:Connection startElement="{a}" startConnector="{y}" '
            f'endElement="{b}" endConnector="{u}"/>\n'
        )
    out.append("    </ssd:Connections>\n  </ssd:System>\n</ssd:SystemStructureDescription>\n")
    return "".join(out)


def write_ssp(path: Path, ssd: str, fmus: dict[str, Path]) -> Path:
    """An .ssp archive with ``SystemStructure.ssd`` and each FMU under its archive name."""
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("SystemStructure.ssd", ssd)
        for name, fmu in fmus.items():
            archive.write(fmu, name)
    return path
