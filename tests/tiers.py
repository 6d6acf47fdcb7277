"""Test tiers, decided from what a test does rather than marked by hand.

``pytest -q`` runs the fast tier: unit tests and in-process tests on real FMUs. A test leaves it for

- ``integration`` when it starts a process (``subprocess``, a node process, an isolated plant's
  child, a multiprocessing worker, ``workers=`` more than one) or opens a Zenoh session (the
  ``loopback`` router);
- ``slow`` when it trains an agent (``agents.train.train``, the ``train`` and ``sweep`` commands,
  the session's trained ``balancer``);
- ``ros`` (tests/ros, marked by its conftest) and ``ray`` (tests/on_ray).

What a test does is read from its code: the test function, the fixtures it requests (and theirs),
and every function of tests/ they call, followed through their globals, so a helper two calls
away that starts a node counts. Markers written by hand stay; this only adds. At run time,
:func:`guard_fast_tier` fails a fast-tier test that still starts a subprocess, naming the marker
it needs, so a test this reading misses cannot stay in the wrong tier unnoticed.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import inspect
import multiprocessing.util
import re
import sys
import textwrap
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import FunctionType
from typing import Any

import pytest

TESTS = Path(__file__).resolve().parent

TIERS = ("slow", "integration", "ros", "ray")
# The default selection (pyproject.toml's addopts says the same): the fast tier.
FAST = "not slow and not integration and not ros and not ray"

# Names whose use starts a process or a networked session: integration.
_PROCESS_NAMES = frozenset(
    {
        "Popen",
        "multiprocessing",
        "get_context",
        "node_process",
        "run_pytest",
        "router_on_loopback",
        "open_session",
        "IsolatedFmuPlant",
        "ProcessPoolExecutor",
    }
)
# Module functions that start a process (the module's name alone, e.g. in an except clause, does not).
_STARTS_A_PROCESS = {
    "subprocess": frozenset({"run", "call", "check_call", "check_output", "getoutput", "getstatusoutput"}),
    "os": frozenset({"system", "popen", "posix_spawn", "posix_spawnp", "fork", "spawnv", "execv"}),
}
# Words in strings or keywords that ask for an isolated plant (a child process): integration.
_ISOLATE_WORDS = frozenset({"isolate", "--isolate", "isolated"})
# Processes that are not under test: the C compiler builds an example FMU or a native helper the
# first time a test needs it (the content-addressed cache keeps it from then on); Python's
# platform module asks `uname -p` once per process for the processor's name (torch and SB3 do),
# and ctypes.util.find_library asks `ldconfig -p` where a shared library is.
_NOT_UNDER_TEST = re.compile(r"(?:[\w.-]+-)?(?:gcc|cc|clang)(?:-[\d.]+)?|uname|ldconfig(?:\.real)?")
# Names whose use trains an agent: slow.
_TRAINING_NAMES = frozenset({"train", "balancer", "learn"})
# CLI commands that train (run in process with typer's CliRunner or as a subprocess): slow.
_TRAINING_COMMANDS = frozenset({"train", "sweep"})


def _is_ours(obj: object) -> bool:
    code = getattr(obj, "__code__", None)
    if code is None:
        return False
    try:
        return TESTS in Path(code.co_filename).resolve().parents
    except (OSError, ValueError):
        return False


@functools.cache
def _tree(function: FunctionType) -> ast.AST | None:
    try:
        return ast.parse(textwrap.dedent(inspect.getsource(function)))
    except (OSError, TypeError, SyntaxError):
        return None


def _walk(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree`` but those inside ``with build_step():`` (a build, not under test)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.With | ast.AsyncWith) and any(
            isinstance(i.context_expr, ast.Call) and _dotted(i.context_expr.func).endswith("build_step")
            for i in node.items
        ):
            continue
        yield node
        todo.extend(ast.iter_child_nodes(node))


def _dotted(node: ast.AST) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return ""


@functools.cache
def _direct(function: FunctionType) -> tuple[frozenset[str], tuple[Callable[..., Any], ...]]:
    """The signals in one function's own code, and the functions of tests/ it refers to."""
    tree = _tree(function)
    if tree is None:
        return frozenset(), ()
    names: set[str] = set()
    words: set[str] = set()
    workers: list[ast.expr] = []  # evaluation workers: processes when more than one
    for node in _walk(tree):
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
            if node.attr in _STARTS_A_PROCESS.get(_dotted(node.value), ()):
                names.add("Popen")  # subprocess.run(...), os.system(...): a process
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            words.add(node.value)
        elif isinstance(node, ast.keyword) and node.arg == "workers":
            workers.append(node.value)
        elif isinstance(node, ast.keyword) and node.arg is not None:
            if not (isinstance(node.value, ast.Constant) and node.value.value in (False, None)):
                words.add(node.arg)
        elif isinstance(node, ast.arg):
            names.add(node.arg)  # a fixture requested as a parameter
    signals = set()
    if names & _PROCESS_NAMES:
        signals.add("integration")
    if words & _ISOLATE_WORDS:
        signals.add("isolate")
    if names & _TRAINING_NAMES or words & _TRAINING_COMMANDS:
        signals.add("slow")
    for value in workers:
        if isinstance(value, ast.Constant) and isinstance(value.value, int) and value.value > 1:
            signals.add("integration")
        elif isinstance(value, ast.Name):
            signals.add(f"workers={value.id}")  # a parameter of the test: its value decides
    scope = function.__globals__
    called = tuple(
        obj
        for name in sorted(names)
        if (obj := scope.get(name)) is not None and obj is not function and _is_ours(obj)
    )
    return frozenset(signals), called


def _reached(roots: list[Callable[..., Any]]) -> Iterator[FunctionType]:
    seen: set[int] = set()
    todo = list(roots)
    while todo:
        function = inspect.unwrap(todo.pop())
        if not isinstance(function, FunctionType) or id(function) in seen:
            continue
        seen.add(id(function))
        yield function
        todo.extend(_direct(function)[1])


def tiers_of(item: pytest.Function) -> set[str]:
    """The tiers the code reached from ``item`` calls for (empty: the fast tier)."""
    roots: list[Callable[..., Any]] = [item.function]
    for definitions in item._fixtureinfo.name2fixturedefs.values():
        roots.extend(d.func for d in definitions if _is_ours(inspect.unwrap(d.func)))
    signals: set[str] = set()
    for function in _reached(roots):
        signals |= _direct(function)[0]
    params = getattr(item, "callspec", None)
    values = dict(params.params) if params is not None else {}
    for signal in [s for s in signals if s.startswith("workers=")]:
        signals.discard(signal)
        count = values.get(signal.partition("=")[2], 2)  # not a parameter: taken as several
        if not isinstance(count, int) or count > 1:
            signals.add("integration")
    if "isolate" in signals:
        signals.discard("isolate")
        chosen = {k: v for k, v in values.items() if "isolat" in k}
        # a parametrised test whose isolate parameter is off runs in process
        if not chosen or any(bool(v) for v in chosen.values()):
            signals.add("integration")
    return signals


def mark_tiers(items: list[pytest.Item]) -> None:
    """Add the tier markers :func:`tiers_of` finds; tests/on_ray is the ``ray`` tier."""
    ray = TESTS / "on_ray"
    for item in items:
        if ray in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.ray)
        if isinstance(item, pytest.Function):
            for tier in sorted(tiers_of(item)):
                item.add_marker(getattr(pytest.mark, tier))


def in_fast_tier(item: pytest.Item) -> bool:
    return not any(item.get_closest_marker(tier) for tier in TIERS)


class FastTierGuard:
    """Records the processes a fast-tier test starts while it runs: an audit hook (it cannot be
    removed, so it checks a flag) sees subprocess, posix_spawn and fork; multiprocessing's spawn
    and forkserver start methods raise no audit event, so the one function both start their
    processes with is wrapped to be seen too (it still starts them as before)."""

    def __init__(self) -> None:
        self.watching = False
        self.started: list[str] = []
        sys.addaudithook(self._hook)
        start = multiprocessing.util.spawnv_passfds

        def spawnv_passfds(path: str, args: Sequence[str], passfds: Sequence[int]) -> int:
            if self.watching:
                self.started.append(f"multiprocessing: {path}")
            return start(path, args, passfds)

        multiprocessing.util.spawnv_passfds = spawnv_passfds

    def _hook(self, event: str, args: tuple[Any, ...]) -> None:
        if not self.watching or event not in ("subprocess.Popen", "os.posix_spawn", "os.fork"):
            return
        program = "a fork" if event == "os.fork" else str(args[0] or _first_word(args[1]))
        if _NOT_UNDER_TEST.fullmatch(Path(program).name) is None:
            self.started.append(f"{event}: {program}")


def _first_word(argv: Any) -> str:
    words = argv.split() if isinstance(argv, str | bytes) else list(argv or ())
    return str(words[0]) if words else "?"


@functools.cache
def _guard() -> FastTierGuard:
    return FastTierGuard()  # one per process: an audit hook stays for good


@contextlib.contextmanager
def build_step() -> Iterator[None]:
    """Processes started inside are a build step (an FMU exported by a tool, a download), not
    processes under test: a session fixture asked for in a test's body builds while the test runs."""
    guard = _guard()
    watching, guard.watching = guard.watching, False
    try:
        yield
    finally:
        guard.watching = watching


def guard_fast_tier(item: pytest.Item) -> Iterator[None]:
    """Around a test's call: a fast-tier test that starts a process fails, naming the marker."""
    if not in_fast_tier(item):
        yield
        return
    guard = _guard()
    guard.started.clear()
    guard.watching = True
    try:
        yield
    finally:
        guard.watching = False
    if guard.started:
        pytest.fail(
            f"{item.nodeid} is in the fast tier but started a process ({'; '.join(guard.started[:3])}): "
            "mark it @pytest.mark.integration, or teach tests/tiers.py the helper it calls"
        )
