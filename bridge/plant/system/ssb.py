"""SSP signal dictionaries: signals routed through ``ssd:SignalDictionaryReference`` elements.

A dictionary (``ssd:SignalDictionary``, inline with ``ssb:DictionaryEntry`` elements or an ``.ssb``
file) names signals; a reference to it is an element of the system whose connectors are its
entries. A connection into a reference's entry produces that signal, a connection out of it
consumes it, and every reference to the same dictionary shares its entries (a bus). Here each
consumer becomes a connection from the producer's output to the consumer's input, so the master
sees a plain connection: its transformation is the one on either side (both sides transformed:
refused), and it suppresses unit conversion if either side does. Refused by name: an entry with no
producer or with two, an entry the dictionary does not define, a reference to an unknown
dictionary.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from bridge.errors import ConfigError
from bridge.plant.system.description import Connection

SSD = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
SSB = "{http://ssp-standard.org/SSP1/SystemStructureSignalDictionary}"


@dataclass
class Bus:
    """The dictionaries of a system, its references, and the connections through them."""

    dictionaries: dict[str, set[str]]  # dictionary -> entry names
    references: dict[str, str] = field(default_factory=dict)  # reference element -> dictionary
    producers: dict[tuple[str, str], list[Connection]] = field(default_factory=dict)
    consumers: dict[tuple[str, str], list[Connection]] = field(default_factory=dict)

    def add_reference(self, element: ET.Element, origin: Path) -> None:
        name, dictionary = element.attrib.get("name", ""), element.attrib.get("dictionary", "")
        if dictionary not in self.dictionaries:
            raise ConfigError(
                f"signal dictionary reference {name!r}: dictionary {dictionary!r} is not defined in "
                f"ssd:SignalDictionaries; defined: {sorted(self.dictionaries)} [{origin}]"
            )
        self.references[name] = dictionary

    def add(self, c: Connection, origin: Path) -> bool:
        """Take ``c`` if it runs into or out of a reference (True), else leave it (False)."""
        for end, table in ((c.target, self.producers), (c.source, self.consumers)):
            dictionary = self.references.get(end.component)
            if dictionary is not None:
                if end.variable not in self.dictionaries[dictionary]:
                    raise ConfigError(
                        f"connection {c}: {end.variable!r} is not an entry of signal dictionary "
                        f"{dictionary!r}; entries: {sorted(self.dictionaries[dictionary])} [{origin}]"
                    )
                table.setdefault((dictionary, end.variable), []).append(c)
                return True
        return False

    def routed(self, origin: Path) -> list[Connection]:
        """Each consumer of an entry connected to the entry's one producer."""
        found = []
        for key, consumers in self.consumers.items():
            producers = self.producers.get(key, [])
            if len(producers) != 1:
                raise ConfigError(
                    f"signal dictionary {key[0]!r}, entry {key[1]!r}: {len(producers)} connections produce "
                    f"it ({[str(p) for p in producers]}); an entry read by {[str(c) for c in consumers]} "
                    f"needs exactly one [{origin}]"
                )
            (producer,) = producers
            for consumer in consumers:
                if producer.transform is not None and consumer.transform is not None:
                    raise ConfigError(
                        f"signal dictionary {key[0]!r}, entry {key[1]!r}: {producer} and {consumer} are "
                        f"both transformed; transform on one side only [{origin}]"
                    )
                found.append(
                    Connection(
                        producer.source,
                        consumer.target,
                        producer.transform or consumer.transform,
                        producer.suppress_units or consumer.suppress_units,
                    )
                )
        return found


def read_dictionaries(system: ET.Element, root: Path, origin: Path) -> dict[str, set[str]]:
    """Every dictionary of ``system`` and its entry names (inline, or from its ``.ssb`` source)."""
    box = system.find(f"{SSD}SignalDictionaries")
    dictionaries: dict[str, set[str]] = {}
    for dictionary in list(box) if box is not None else []:
        name = dictionary.attrib.get("name", "")
        content: ET.Element = dictionary
        if "source" in dictionary.attrib:
            path = root / dictionary.attrib["source"]
            try:
                content = ET.parse(path).getroot()
            except (ET.ParseError, OSError) as exc:
                raise ConfigError(
                    f"signal dictionary {name!r}: cannot read {path.name}: {exc} [{origin}]"
                ) from exc
        dictionaries[name] = {e.attrib.get("name", "") for e in content.iter(f"{SSB}DictionaryEntry")}
    return dictionaries
