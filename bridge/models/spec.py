"""The in-memory form of a ``model.json``: variables, enumeration types and the variants to build.

These frozen dataclasses are what the C and XML generators read; :mod:`bridge.models.sources`
fills them from the files. Type, causality and variability names are the FMI 3.0 ones; the
FMI 1.0/2.0 element names are mapped where the XML is written.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Final

FMI_VERSIONS: Final = ("1.0", "2.0", "3.0")
INTERFACES: Final = ("cs", "me")

FLOAT_TYPES: Final = frozenset({"Float32", "Float64"})
UNSIGNED_TYPES: Final = frozenset({"UInt8", "UInt16", "UInt32", "UInt64"})
INT_TYPES: Final = frozenset({"Int8", "Int16", "Int32", "Int64"}) | UNSIGNED_TYPES
ALL_TYPES: Final = FLOAT_TYPES | INT_TYPES | {"Boolean", "String", "Enumeration", "Binary", "Clock"}
#: FMI 1.0/2.0 element names of the types that exist there (model.json uses the FMI 3.0 names).
FMI2_TYPES: Final = dict(
    Float64="Real", Int32="Integer", Boolean="Boolean", String="String", Enumeration="Enumeration"
)
CAUSALITIES: Final = ("parameter", "calculatedParameter", "input", "output", "local", "independent")
VARIABILITIES: Final = ("constant", "fixed", "tunable", "discrete", "continuous")

Scalar = float | int | bool | str
#: A start value: a scalar, one float per element of a Float64 array, or a Binary's bytes as hex text.
Start = Scalar | tuple[float, ...]


@dataclass(frozen=True)
class Variable:
    """One model variable; value references count from 1 in file order (0 is ``time``)."""

    vr: int
    name: str
    type: str
    causality: str
    variability: str
    initial: str | None
    description: str
    start: Start | None = None
    unit: str | None = None
    min: float | None = None
    max: float | None = None
    nominal: float | None = None
    declared_type: str | None = None
    derivative: str | None = None
    fmi_versions: tuple[str, ...] = FMI_VERSIONS
    interfaces: tuple[str, ...] = INTERFACES
    dimensions: tuple[int, ...] = ()  # FMI 3.0 arrays (Float64 only): sizes, row-major
    interval: float | None = None  # FMI 3.0 Clock: constant interval in s
    c: str | None = None  # the C identifier, when the one derived from the name does not fit

    @property
    def size(self) -> int:
        """Number of elements: the product of the dimensions, 1 for a scalar."""
        count = 1
        for n in self.dimensions:
            count *= n
        return count

    @property
    def c_name(self) -> str:
        """The identifier of the C struct field and of ``VR_<c_name>``: ``c`` if given, else derived."""
        return self.c if self.c is not None else c_identifier(self.name)

    def present_in(self, fmi_version: str, interface: str) -> bool:
        """Whether the variable appears in this variant's modelDescription.xml (the C struct has all)."""
        in_interface = interface in self.interfaces and (self.derivative is None or interface == "me")
        return fmi_version in self.fmi_versions and in_interface


_NOT_C: Final = re.compile(r"[^A-Za-z0-9_]+")


def c_identifier(name: str) -> str:
    """The C identifier derived from a variable name (Modelica-style names included).

    ``der(x)`` gives ``der_`` and the identifier of ``x``; an ASCII identifier stays as it is; in any
    other name each run of characters outside ``[A-Za-z0-9_]`` becomes one ``_`` and ``_`` is stripped
    from both ends: ``body.frame_a.r_0[1]`` gives ``body_frame_a_r_0_1``, ``'force in N'`` gives
    ``force_in_N``. The result may still be unusable (a leading digit, a C keyword, two names giving the
    same identifier): the spec check reports that and asks for an explicit ``c``.
    """
    if name.startswith("der(") and name.endswith(")"):
        return "der_" + c_identifier(name[4:-1])
    if name.isascii() and name.isidentifier():
        return name
    return _NOT_C.sub("_", name).strip("_")


VARIABLE_KEYS: Final = frozenset(f.name for f in fields(Variable)) - {"vr"}

#: The independent variable every model has; FMI 1.0 has no ``time`` variable.
TIME: Final = Variable(
    vr=0,
    name="time",
    type="Float64",
    causality="independent",
    variability="continuous",
    initial=None,
    description="Simulation time",
    unit="s",
    fmi_versions=("2.0", "3.0"),
)


@dataclass(frozen=True)
class EnumType:
    """An enumeration from ``type_definitions``."""

    name: str
    description: str
    items: tuple[tuple[str, int, str], ...]  # (name, value, description)


@dataclass(frozen=True)
class Spec:
    """A parsed ``model.json`` and the directory it came from."""

    name: str
    directory: Path
    description: str
    variants: tuple[tuple[str, str], ...]
    default_experiment: Mapping[str, float]
    max_step_s: float | None
    event_indicators: tuple[str, ...]
    enums: Mapping[str, EnumType]
    variables: tuple[Variable, ...]
    once_per_process: bool = False  # canBeInstantiatedOnlyOncePerProcess (and no FMU state): globals
    can_serialize: bool = False  # canSerializeFMUstate: the state as bytes (no String/Binary variables)
    state_after_init: bool = False  # a state is set or deserialised only once initialised
    cs_derivatives: bool = False  # co-simulation lists the state derivatives too (<Derivatives>)
    equations: str | None = None  # another model whose model.c this one compiles (the same equations)

    @property
    def c_source(self) -> Path:
        """The model's C equations: its own ``model.c``, or the one of the model named by ``equations``."""
        return (self.directory.parent / self.equations if self.equations else self.directory) / "model.c"

    def variable(self, name: str) -> Variable:
        return next(v for v in self.variables if v.name == name)

    def states(self) -> list[tuple[Variable, Variable]]:
        """(state, derivative) pairs in derivative declaration order."""
        return [(self.variable(d.derivative), d) for d in self.variables if d.derivative is not None]

    def variant_variables(self, fmi_version: str, interface: str) -> list[Variable]:
        return [v for v in self.variables if self.exposes(v, fmi_version, interface)]

    def exposes(self, v: Variable, fmi_version: str, interface: str) -> bool:
        """Whether ``v`` is in this variant's modelDescription.xml: derivatives are model
        exchange's, and co-simulation's too where ``derivatives_in_cs`` says so."""
        if v.derivative is not None and interface == "cs" and self.cs_derivatives:
            return fmi_version in v.fmi_versions
        return v.present_in(fmi_version, interface)
