"""What an experiment file may name: file-safe names and the Python code it may call.

An experiment file is data a user may have been handed. Its ``name`` becomes part of file and
folder names (recordings, training runs), so it is restricted to letters, digits, ``.``, ``_`` and
``-``, starting with a letter or digit, at most :data:`MAX_NAME_CHARS` long: no separators, no
``..``, no control or bidirectional characters. Its ``module:function`` references
(``reward.callable``, ``hooks.*``, baselines, metrics) are called with the env's values, so they
may only name the user's own modules: not the standard library, not installed packages
(``os:system`` would run a shell command per step), not fmu-bridge's own packages (``bridge``,
``agents``: its CLI and training are not rewards) and not ``__main__`` (whatever program runs);
names must be absolute dotted Python names (no relative ``.mod``, no control characters), unless
the user lists a module in the
environment variable :data:`ALLOW_ENV` (comma-separated module names; a name allows its
submodules). The list lives outside the file on purpose: a file cannot allow itself.
"""

from __future__ import annotations

import importlib.util
import os
import re
import sys
import sysconfig
from pathlib import Path

MAX_NAME_CHARS = 100
ALLOW_ENV = "FMU_BRIDGE_ALLOWED_MODULES"
_PACKAGES = {"site-packages", "dist-packages"}
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_LEADING = re.compile(r"^[^A-Za-z0-9]+")


def check_safe_name(value: str) -> str:
    """``value`` if it is a safe file-name part, else a ValueError saying what is allowed."""
    if len(value) > MAX_NAME_CHARS:
        raise ValueError(
            f"a name of {len(value):,} characters; use at most {MAX_NAME_CHARS} letters, digits, '.', "
            "'_' and '-' (it becomes part of file names)"
        )
    if not _NAME.fullmatch(value):
        raise ValueError(
            f"{_shown(value)} is not a plain name: use letters, digits, '.', '_' and '-', starting "
            "with a letter or digit (it becomes part of file names)"
        )
    return value


def safe_name(text: str, fallback: str = "experiment") -> str:
    """``text`` made into a name :func:`check_safe_name` accepts (for ``init``: a model's name).

    Runs of anything but letters, digits, ``.``, ``_`` and ``-`` become one ``_``; leading
    characters that cannot start a name are dropped; the result is cut to :data:`MAX_NAME_CHARS`.
    ``"van der pol oscillator"`` gives ``"van_der_pol_oscillator"``; a name with nothing usable
    gives ``fallback``.
    """
    name = _UNSAFE.sub("_", text.strip())
    name = _LEADING.sub("", name)[:MAX_NAME_CHARS].rstrip("._-") or fallback
    return check_safe_name(name)


def _shown(value: str) -> str:
    """``value`` quoted with control and bidirectional characters escaped, cut to 60 characters."""
    text = value if len(value) <= 60 else value[:57] + "..."
    return ascii(text)


_PROJECT = ("bridge", "agents")  # fmu-bridge's own packages


def check_module_name(module: str) -> None:
    """Raise ValueError unless ``module`` is an absolute dotted name of Python identifiers."""
    if not module or not all(part.isidentifier() for part in module.split(".")):
        raise ValueError(
            f"{_shown(module)} is not a module name: use an absolute dotted Python name such as "
            "'my_rewards' or 'my_package.rewards' (no leading dot, spaces or control characters)"
        )


def check_own_module(module: str) -> None:
    """Raise ValueError unless ``module`` is the user's own code or allowed through ALLOW_ENV."""
    check_module_name(module)
    if _allowed(module):
        return
    top = module.partition(".")[0]
    if top == "__main__" or top in _PROJECT:
        what = "the program that is running" if top == "__main__" else "part of fmu-bridge itself"
        raise ValueError(
            f"{module!r} is {what}, not a module of your own; experiment files may call only your "
            f"own modules: put the function in a module of yours (to allow it anyway, list it in "
            f"the environment variable {ALLOW_ENV})"
        )
    where = _origin(top)
    if top in sys.stdlib_module_names or top in sys.builtin_module_names:
        where = "library"
    if where in ("library", "installed"):
        what = "part of Python's standard library" if where == "library" else "an installed package"
        raise ValueError(
            f"{module!r} is {what}, not a module of your own; experiment files may call "
            f"only your own modules. To allow it, list it in the environment variable {ALLOW_ENV} "
            f"(e.g. {ALLOW_ENV}={top})"
        )


def _allowed(module: str) -> bool:
    listed = [m.strip() for m in os.environ.get(ALLOW_ENV, "").split(",") if m.strip()]
    return any(module == m or module.startswith(m + ".") for m in listed)


def _origin(top: str) -> str:
    """``library`` (the standard library), ``installed`` (site-packages), ``own`` or ``unknown``."""
    try:
        spec = importlib.util.find_spec(top)  # a top-level name: finding it runs no module code
    except (ImportError, ValueError):
        return "unknown"
    if spec is None:
        return "unknown"
    if spec.origin in (None, "built-in", "frozen") and not spec.submodule_search_locations:
        return "library"
    places = [spec.origin] if spec.origin not in (None, "namespace") else []
    places += list(spec.submodule_search_locations or [])
    paths = sysconfig.get_paths()
    installed = {Path(paths[k]).resolve() for k in ("purelib", "platlib")}
    library = {Path(paths[k]).resolve() for k in ("stdlib", "platstdlib")}
    for place in places:
        resolved = Path(place).resolve()
        if any(resolved.is_relative_to(p) for p in installed) or _PACKAGES & set(resolved.parts):
            return "installed"
        if any(resolved.is_relative_to(p) for p in library):
            return "library"
    return "own"
