"""No module outside ``bridge/fmu/model.py`` touches a ``Model`` member whose name starts with ``_``.

The native sample, the batch, the system's native master and state-file starts step an instance
through the public members of :class:`bridge.fmu.instance.Instance` ("the stepping interface");
this scan of ``bridge/`` and ``agents/`` keeps it that way. A ``Model`` private member is any
``_name`` (not ``__dunder__``) that ``Model`` or its base ``Instance`` defines: methods, class
annotations and attributes assigned on ``self``. A module touches one by ``x._name`` on anything
but ``self``/``cls`` (their own members), or by ``getattr``/``setattr``/``hasattr`` with that name.
"""

from __future__ import annotations

import ast
from pathlib import Path

import bridge

ROOT = Path(bridge.__file__).resolve().parent.parent
OWNERS = {"model.py": "Model", "instance.py": "Instance"}  # in bridge/fmu/
# Receivers known not to be a Model that share a private name with it, with why.
NOT_A_MODEL = {
    ("agents/deploy_lifecycle.py", "outer"): "the deployed agent's lifecycle node (its own _configure)",
}


def _privates(source: str, class_name: str) -> set[str]:
    """The single-underscore members ``class_name`` defines in ``source``."""
    cls = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == class_name)
    names: set[str] = set()
    for node in ast.walk(cls):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self":
            names.add(node.attr)
    return {n for n in names if n.startswith("_") and not n.startswith("__")}


def model_privates() -> set[str]:
    fmu = ROOT / "bridge" / "fmu"
    return set().union(*(_privates((fmu / f).read_text(), c) for f, c in OWNERS.items()))


def _reflective(node: ast.Call) -> bool:
    """``getattr(x, name, ...)``, ``setattr`` or ``hasattr``."""
    if not isinstance(node.func, ast.Name):
        return False
    return node.func.id in ("getattr", "setattr", "hasattr") and len(node.args) >= 2


def touches(source: str, privates: set[str]) -> list[tuple[int, str, str]]:
    """(line, receiver, name) of every access to one of ``privates`` on something but self/cls."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr in privates:
            receiver = ast.unparse(node.value)
            if receiver not in ("self", "cls"):
                found.append((node.lineno, receiver, node.attr))
        elif isinstance(node, ast.Call) and _reflective(node):
            name = node.args[1]
            if isinstance(name, ast.Constant) and name.value in privates:
                found.append((node.lineno, ast.unparse(node.args[0]), str(name.value)))
    return sorted(found)


def test_the_scan_sees_the_stepping_state_and_an_access_to_it() -> None:
    privates = model_privates()
    assert {"_backend", "_clock", "_me", "_initialize", "_snapshots"} <= privates
    # what the native sample did before the stepping interface: caught
    old = "h = model._native_handles()\nrefs = ctypes.byref(model._clock)\nx = getattr(m, '_backend')\n"
    assert sorted(touches(old, privates | {"_native_handles"})) == [
        (1, "model", "_native_handles"),
        (2, "model", "_clock"),
        (3, "m", "_backend"),
    ]
    assert touches("self._clock.value = 0\n", privates) == []


def test_no_module_outside_model_py_touches_a_model_private_member() -> None:
    privates = model_privates()
    offenders = []
    for path in sorted([*(ROOT / "bridge").rglob("*.py"), *(ROOT / "agents").rglob("*.py")]):
        relative = path.relative_to(ROOT).as_posix()
        if relative == "bridge/fmu/model.py":
            continue
        for line, receiver, name in touches(path.read_text(), privates):
            if (relative, receiver) not in NOT_A_MODEL:
                offenders.append(f"{relative}:{line}: {receiver}.{name}")
    assert not offenders, (
        "these modules touch Model's private members; step the instance through the public members "
        "of bridge.fmu.instance.Instance (the stepping interface), or add one there:\n" + "\n".join(offenders)
    )
