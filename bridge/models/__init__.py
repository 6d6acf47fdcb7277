"""Example FMUs of fmu-bridge: our own C models, built into standard ``.fmu`` archives on demand.

Each model lives in ``models/<name>/`` as ``model.json`` (every variable defined once) and ``model.c``
(the equations, or ``"equations": "<model>"`` in ``model.json`` to compile that model's), over a shared C
framework in ``models/common/``. For a variant (FMI version and
interface) this package generates ``modelDescription.xml`` and a C header/table of value references
from ``model.json``, so the XML and the C code cannot drift, compiles everything with gcc against the
FMI headers that FMPy ships, and zips the result. Archives are cached per user, keyed by a hash of
the sources and of this generator, and written atomically so that parallel processes never see a
half-written file.

The work is split by step: :mod:`~bridge.models.sources` finds and reads ``model.json`` into the
dataclasses of :mod:`~bridge.models.spec`; :mod:`~bridge.models.ccode` and
:mod:`~bridge.models.description` generate the C and the XML; :mod:`~bridge.models.build` runs gcc,
computes the cache key and writes the archive.

Example:
    >>> from bridge.models import example_fmu
    >>> path = example_fmu("cartpole", "3.0", "cs")  # builds once, then returns the cached archive
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from bridge.errors import ConfigError
from bridge.models.build import CFLAGS, build_archive, cache_dir, cache_key
from bridge.models.sources import load_spec, model_names
from bridge.models.spec import FMI_VERSIONS, INTERFACES, Spec

__all__ = [
    "CFLAGS",
    "FMI_VERSIONS",
    "INTERFACES",
    "ModelVariant",
    "build_all",
    "cache_dir",
    "example_fmu",
    "handwritten_variants",
    "list_variants",
    "model_names",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ModelVariant:
    """One buildable example FMU.

    Attributes:
        name: model name, the directory under ``models/`` and the FMI modelIdentifier.
        fmi_version: ``"1.0"``, ``"2.0"`` or ``"3.0"``.
        interface: ``"cs"`` (co-simulation) or ``"me"`` (model exchange).
        description: what the model is, from its ``model.json``.
    """

    name: str
    fmi_version: str
    interface: str
    description: str

    @property
    def label(self) -> str:
        """Human-readable name, e.g. ``cartpole FMI 2.0 CS``."""
        return f"{self.name} FMI {self.fmi_version} {self.interface.upper()}"


def list_variants() -> list[ModelVariant]:
    """Every buildable (model, FMI version, interface) combination, sorted by model name."""
    variants = []
    for name in model_names():
        spec = load_spec(name)
        variants += [
            ModelVariant(name, version, interface, spec.description) for version, interface in spec.variants
        ]
    return variants


def example_fmu(name: str, fmi_version: str = "2.0", interface: str = "cs", *, rebuild: bool = False) -> Path:
    """Path of the example FMU ``name`` for an FMI version and interface, building it if needed.

    Args:
        name: model name, one of :func:`model_names`.
        fmi_version: ``"1.0"``, ``"2.0"`` or ``"3.0"``.
        interface: ``"cs"`` (co-simulation) or ``"me"`` (model exchange).
        rebuild: compile again even if a cached archive with the same source hash exists.

    Raises:
        ConfigError: the model or the variant does not exist (the message lists what does).
        DependencyMissing: gcc or FMPy (for the FMI headers) is not installed.
        BridgeError: gcc failed; the message carries its output.
    """
    if name in HANDWRITTEN:
        return _handwritten(name, fmi_version, interface, rebuild=rebuild)
    spec = load_spec(_check_name(name))
    _check_variant(spec, fmi_version, interface)
    key = cache_key(spec, fmi_version, interface)
    target = cache_dir() / f"{name}-fmi{fmi_version[0]}-{interface}-{key[:16]}.fmu"
    if target.is_file() and not rebuild:
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    build_archive(spec, fmi_version, interface, key, target)
    logger.info("built %s", target)
    return target


def build_all(variants: Sequence[ModelVariant] | None = None, *, rebuild: bool = False) -> list[Path]:
    """Build (or find in the cache) ``variants`` (every variant of every generated example model by
    default); gcc runs in parallel.

    Returns:
        The archive paths in the order of ``variants`` (of :func:`list_variants` by default).
    """
    variants = list_variants() if variants is None else variants
    with ThreadPoolExecutor(max_workers=min(8, os.cpu_count() or 1)) as pool:
        futures = [
            pool.submit(example_fmu, v.name, v.fmi_version, v.interface, rebuild=rebuild) for v in variants
        ]
        return [future.result() for future in futures]


#: Example models written without model.json (their own C and XML):
#: name -> (FMI version, interfaces, description).
HANDWRITTEN: dict[str, tuple[str, tuple[str, ...], str]] = {
    "strict_arrays": (
        "3.0",
        ("cs", "me"),
        "Strict FMI 3.0 arrays: u[n] in, y[2,n] out, sized by the structural parameter n (start 3); "
        "refuses element-wise calls (docs/arrays.md). One archive holds both interfaces.",
    ),
    "clocks3": (
        "3.0",
        ("cs", "me", "se"),
        "FMI 3.0 clocks of every time-based kind, a triggered input and output clock, and a clocked "
        "controller; co-simulation with event mode, model exchange, or scheduled execution (docs/clocks.md).",
    ),
}


def handwritten_variants() -> list[ModelVariant]:
    """The variants of :data:`HANDWRITTEN` (``fmu-bridge models`` lists them after the others)."""
    return [
        ModelVariant(name, version, interface, description)
        for name, (version, interfaces, description) in HANDWRITTEN.items()
        for interface in interfaces
    ]


def _handwritten(name: str, fmi_version: str, interface: str, *, rebuild: bool) -> Path:
    version, interfaces, _ = HANDWRITTEN[name]
    if fmi_version != version or interface not in interfaces:
        raise ConfigError(
            f"{name} has no FMI {fmi_version!r} {interface!r} variant; available: fmi_version={version!r} "
            f"interface one of {interfaces}"
        )
    if name == "strict_arrays":
        from bridge.models.strict import strict_arrays_fmu

        return strict_arrays_fmu(rebuild=rebuild)
    from bridge.models.clocked import clocks_fmu

    return clocks_fmu(interface, rebuild=rebuild)


def _check_name(name: str) -> str:
    names = model_names()
    if name not in names:
        available = ", ".join([*names, *HANDWRITTEN])
        raise ConfigError(f"model {name!r} is not an example model; available: {available}")
    return name


def _check_variant(spec: Spec, fmi_version: str, interface: str) -> None:
    if (fmi_version, interface) in spec.variants:
        return
    available = ", ".join(f"fmi_version={v!r} interface={i!r}" for v, i in spec.variants)
    raise ConfigError(
        f"{spec.name} has no FMI {fmi_version!r} {interface!r} variant (fmi_version is one of "
        f"{FMI_VERSIONS}, interface one of {INTERFACES}); available for {spec.name}: {available}"
    )
