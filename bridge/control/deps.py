"""The control extra's optional packages (scipy, OSQP), imported only when a design needs them."""

from __future__ import annotations

import importlib
from types import ModuleType

from bridge.errors import DependencyMissing

INSTALL_HINT = 'pip install "fmu-bridge[control]"'


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` (e.g. ``scipy.linalg``, ``osqp``) or raise the install hint for ``purpose``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise DependencyMissing(module.split(".", maxsplit=1)[0], purpose, INSTALL_HINT) from exc
