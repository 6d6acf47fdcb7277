"""SSP signal dictionaries: signals routed through ``ssd:SignalDictionaryReference`` elements.

A dictionary (``ssd:SignalDictionary``, inline with ``ssb:DictionaryEntry`` elements or an ``.ssb``
file) names signals; a reference to it is an element of the system whose connectors are its
entries. A connection into a reference's entry produces that signal, a connection out of it
consumes it, and every reference to the same dictionary shares its entries (a bus). Here each
consumer becomes a connection from the producer's output to the consumer's input, so the master
sees a plain connection: its transformation is the one along the way (two transformed
connections on one path: refused), and it suppresses unit conversion if any connection on the
path does. Nested systems route the same way: a nested system's connectors are the entries, the
connections into and out of them from either side the producers and consumers. Refused by name:
an entry with no producer or with two, an entry the dictionary does not define, a reference to an
unknown dictionary, entries that feed each other in a cycle.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from bridge.errors import ConfigError
from bridge.plant.system.structure import Connection, Endpoint

SSD = "{http://ssp-standard.org/SSP1/SystemStructureDescription}"
SSB = "{http://ssp-standard.org/SSP1/SystemStructureSignalDictionary}"


@dataclass
class Bus:
    """The dictionaries of a system, its references, and the connections through them."""

    dictionaries: dict[str, set[str]]  # dictionary -> entry names
    references: dict[str, str] = field(default_factory=dict)  # reference element -> dictionary
    producers: dict[tuple[str, str], list[Connection]] = field(default_factory=dict)
    consumers: dict[tuple[str, str], list[Connection]] = field(default_factory=dict)
    systems: set[str] = field(default_factory=set)  # nested systems among the references

    def add_reference(self, element: ET.Element, origin: Path, prefix: str = "") -> None:
        name, dictionary = prefix + element.attrib.get("name", ""), element.attrib.get("dictionary", "")
        if dictionary not in self.dictionaries:
            raise ConfigError(
                f"signal dictionary reference {name!r}: dictionary {dictionary!r} is not defined in "
                f"ssd:SignalDictionaries; defined: {sorted(self.dictionaries)} [{origin}]"
            )
        self.references[name] = dictionary

    def add_system(self, name: str, connectors: list[str]) -> None:
        """A nested system: its connectors carry signals in and out as a dictionary's entries."""
        self.dictionaries[name] = set(connectors)
        self.references[name] = name
        self.systems.add(name)

    def add(self, c: Connection, origin: Path) -> bool:
        """Take ``c`` if it runs into or out of a reference (True), else leave it (False)."""
        taken = False
        for end, table in ((c.target, self.producers), (c.source, self.consumers)):
            key = self._key(end, c, origin)
            if key is not None:
                table.setdefault(key, []).append(c)
                taken = True
        return taken

    def _key(self, end: Endpoint, c: Connection, origin: Path) -> tuple[str, str] | None:
        dictionary = self.references.get(end.component)
        if dictionary is None:
            return None
        if end.variable not in self.dictionaries[dictionary]:
            what = "a connector of system" if dictionary in self.systems else "an entry of signal dictionary"
            raise ConfigError(
                f"connection {c}: {end.variable!r} is not {what} {dictionary!r}; entries: "
                f"{sorted(self.dictionaries[dictionary])} [{origin}]"
            )
        return dictionary, end.variable

    def routed(self, origin: Path) -> list[Connection]:
        """Each consumer of an entry that is a component connected to the entry's producer,
        followed back through other entries to a component's output."""
        found = []
        for key, consumers in self.consumers.items():
            for consumer in consumers:
                if consumer.target.component in self.references:
                    continue  # an entry feeding another: its own consumers follow it back
                source, chain = self._source(key, consumer, origin, {key})
                transforms = [t for t in (*chain, consumer) if t.transform is not None]
                if len(transforms) > 1:
                    raise ConfigError(
                        f"{consumer.target} is fed through {[str(t) for t in transforms]}, more than one "
                        f"transformed connection; transform on one of them only [{origin}]"
                    )
                transform = transforms[0].transform if transforms else None
                suppress = any(t.suppress_units for t in (*chain, consumer))
                found.append(Connection(source, consumer.target, transform, suppress))
        return found

    def _source(
        self, key: tuple[str, str], consumer: Connection, origin: Path, seen: set[tuple[str, str]]
    ) -> tuple[Endpoint, list[Connection]]:
        producers = self.producers.get(key, [])
        if len(producers) != 1:
            raise ConfigError(
                f"signal dictionary or system {key[0]!r}, entry {key[1]!r}: {len(producers)} connections "
                f"produce it ({[str(p) for p in producers]}); {consumer} reads it and needs exactly one "
                f"[{origin}]"
            )
        (producer,) = producers
        upstream = self._key(producer.source, producer, origin)
        if upstream is None:
            return producer.source, [producer]
        if upstream in seen:
            raise ConfigError(
                f"signal dictionary or system {key[0]!r}: entries feed each other in a cycle [{origin}]"
            )
        source, chain = self._source(upstream, consumer, origin, seen | {upstream})
        return source, [*chain, producer]


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
