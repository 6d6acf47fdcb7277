"""``IsolatedFmuPlant``: the FMU in a child process, behind a per-call deadline.

An FMU is native code from someone else. In this process a segfault kills the trainer, an
endless loop in ``doStep`` hangs it for good and a leak grows without bound. Here the FMU runs
in a child process (a ``LocalFmuPlant`` there) and every reset and step waits at most
``timeout_s`` (``model.isolation.timeout``): a hung FMU becomes :class:`StepTimeout`, a crash
:class:`PlantDied` naming the signal (or the exit code of an FMU that ends its process), and a
child whose resident memory grows by more than ``memory_limit_mb`` after loading (a leak; checked
every 32 samples) is stopped with :class:`PlantDied` saying so. The limit also holds before the
fact: the child's address space is capped (``RLIMIT_AS``) at what it had after loading plus twice
``memory_limit_mb``, so one huge allocation fails instead of taking the machine's memory. The
child leads a process group of its own (same session, so the same scheduling group as its parent):
on a deadline or ``close()`` its whole process group is killed (an FMU that forks leaves nothing
behind), and a child whose parent dies kills its group too (no orphan burns a core). With
``restart=True`` the next ``reset()`` starts a fresh child, so a long training run survives an
unstable FMU.

Two waits have no deadline, because only the plant knows how long they take: the child's start
(a fresh interpreter importing fmu-bridge and loading the FMU, slow on a loaded machine) and its first
reset (the FMU's initialisation, minutes for a large model). Both last as long as the child lives:
a child that dies is reported at once, one still busy is logged every 30 s. A later reset may
initialise the FMU again: it may take ``timeout_s`` or four times the first reset, whichever is longer.

Cost: one pipe round trip per sample (see ``benchmarks/bench_env.py --plant isolated``). Use it
for untrusted or unstable FMUs; the in-process plant stays the default.

The child runs a ``LocalFmuPlant`` of the same description (:class:`~bridge.plant.spec.PlantSpec`)
the parent was given, an experiment's FMU and a system's component alike: a system puts every
component whose FMU declares ``canBeInstantiatedOnlyOncePerProcess`` in a process of its own this way.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import signal
import sys
import time
from collections.abc import Mapping, Sequence
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

from bridge.errors import BridgeError, ConfigError, PlantDied, PlantError, StepError, StepTimeout
from bridge.fmu import read_model_info, structure
from bridge.fmu.state_file import StateFile
from bridge.fmu.vocab import ModelInfo
from bridge.plant.base import MODEL_FAILED, MODEL_FAILED_HINT, FloatArray, Plant
from bridge.plant.spec import PlantSpec

_log = logging.getLogger(__name__)
RESET_MARGIN = 4.0  # a later reset may take this many times the first (measured) one
_START_REPORT_S = 30.0  # how often a child that is still starting is reported (INFO)


class IsolatedFmuPlant(Plant):
    """The FMU ``spec`` describes in a child process, every call bounded by ``timeout_s``.

    Args:
        spec: the model and what a sample is (as for ``LocalFmuPlant``, which the child runs).
        timeout_s: the longest a reset or one sample may take before :class:`StepTimeout` (not
            the start, nor the first reset of a child, which initialises the FMU).
        memory_limit_mb: resident memory the child may add after loading the FMU (None: no limit).
        restart: start a fresh child at the next ``reset()`` after a hang or a crash.
    """

    can_set_values = True
    isolated = True

    def __init__(
        self,
        spec: PlantSpec,
        *,
        timeout_s: float = 10.0,
        memory_limit_mb: float | None = None,
        restart: bool = True,
    ) -> None:
        if not timeout_s > 0:
            raise ConfigError(f"timeout_s must be > 0 seconds, got {timeout_s}")
        self.spec = spec
        self.fmu_path = spec.model.fmu
        self.info = _configured_info(spec)
        self.timing = spec.timing
        self.name = spec.named("child process")
        self.timeout_s, self.memory_limit_mb, self.restart = timeout_s, memory_limit_mb, restart
        self.restarts = 0
        self._time_s = self.timing.start_time_s
        self._process: Any = None
        self._conn: Connection | None = None
        self._broken: PlantError | None = None
        self._start_file: tuple[StateFile | None, str] | None = None  # given to every child

    # -- child life cycle ------------------------------------------------------------------------------
    def bind(self, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().bind(input_names, output_names)
        self._start()

    def _start(self) -> None:
        context = mp.get_context("spawn")  # no inherited threads or locks from this process
        parent = child = None
        try:
            parent, child = context.Pipe()
            args = (child, self.spec, self.input_names, self.output_names, self.memory_limit_mb)
            process = context.Process(target=_serve, args=args, name="fmu-plant", daemon=True)
            process.start()
        except (OSError, ValueError) as exc:  # no process: EAGAIN, EMFILE, ENOMEM, a bad executable
            for end in (parent, child):
                if end is not None:
                    end.close()
            raise self.failure(
                PlantDied,
                "the plant's process could not start",
                f"{type(exc).__name__}: {exc}",
                "check the process and file limits (ulimit -u, ulimit -n) and free memory",
                step=None,
                time_s=None,
            ) from None
        self._process = process
        child.close()
        self._conn, self._broken = parent, None
        try:
            self._await_start()
        except PlantDied as exc:
            raise PlantDied(
                f"{self.name}: the plant's process could not start ({exc.detail}); {_start_hint()}",
                plant=self.name,
                detail=exc.detail,
            ) from None
        except BridgeError:  # the FMU did not load in the child: its error, as in process
            self._stop()
            raise
        self._rss_start = _rss_bytes(process.pid or 0)
        self._initialised = False  # its first reset initialises the FMU: no deadline (_await_alive)
        if self._start_file is not None:  # a fresh child starts from the state it was given too
            self._call(("start", *self._start_file), step=None)

    def _await_start(self) -> None:
        """Wait for the child's first answer for as long as it lives (:meth:`_await_alive`)."""
        conn = self._conn
        assert conn is not None
        try:
            conn.send(("hello",))
        except OSError:
            raise self._died(None) from None
        self._await_alive("starting", None)

    def _await_alive(self, doing: str, step: int | None) -> FloatArray:
        """The child's answer, waited for as long as the child lives: a fresh interpreter that
        imports fmu-bridge and loads the FMU, and the FMU's first initialisation, take what they
        take (minutes for a large model, longer on a loaded machine), and no deadline the user did
        not set may end them. A child that dies is reported at once (its end of the pipe closes);
        one still busy is logged every ``_START_REPORT_S``."""
        conn = self._conn
        assert conn is not None
        waited_s = 0.0
        while not conn.poll(_START_REPORT_S):
            waited_s += _START_REPORT_S
            _log.info("%s: its process is still %s after %.0f s", self.name, doing, waited_s)
        return self._answer(0.0, step)

    def _stop(self) -> None:
        process, conn = self._process, self._conn
        self._process = self._conn = None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.send(("close",))
            conn.close()
        if process is not None:
            process.join(timeout=1.0)
            _kill_group(process)
            process.join(timeout=5.0)

    def close(self) -> None:
        self._stop()

    # -- the plant interface ---------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        return self._time_s

    def reset(self, values: Mapping[str, Any], inputs: Sequence[float] | None) -> FloatArray:
        if self._process is not None and self._broken is None and not self._process.is_alive():
            self._broken = self._died(None)  # it ended between calls (killed, or its parent's group)
        if self._broken is not None or self._conn is None:
            if not self.restart and self._broken is not None:
                raise self._broken
            self._stop()
            self._start()
            self.restarts += 1
        self.episode += 1
        self.sample, self.terminated = 0, False
        message = ("reset", dict(values), None if inputs is None else list(inputs))
        try:
            if self._initialised:  # a reset may initialise again: as slow as the first, measured
                outputs = self._call(message, step=None, timeout_s=self._reset_deadline_s())
            else:
                outputs = self._first_reset(message)
        except BridgeError as exc:
            self._unusable = f"the last reset failed: {exc}"
            raise
        self._unusable = None
        return outputs

    def _first_reset(self, message: tuple[Any, ...]) -> FloatArray:
        """The child's first reset initialises the FMU: waited for as long as the child lives."""
        if self._conn is None:
            raise self._died(None)
        try:
            self._conn.send(message)
        except OSError:
            raise self._died(None) from None
        start = time.perf_counter()
        outputs = self._await_alive("initialising the FMU", None)
        self._first_reset_s = time.perf_counter() - start
        self._initialised = True
        return outputs

    def _reset_deadline_s(self) -> float:
        """A later reset's deadline: ``timeout_s``, or ``RESET_MARGIN`` times the first reset
        (the FMU's initialisation, measured) where that is longer."""
        return max(self.timeout_s, RESET_MARGIN * self._first_reset_s)

    def send(self, inputs: Sequence[float] | None) -> None:
        if self._broken is not None:
            raise self._broken
        assert self._conn is not None, "bind() first"
        try:
            self._conn.send(("step", None if inputs is None else list(inputs)))
        except OSError:
            raise self._died(self.sample + 1) from None

    def receive(self) -> FloatArray:
        outputs = self._answer(self.timeout_s, self.sample + 1)
        self.sample += 1
        if self.memory_limit_mb is not None and self.sample % 32 == 0:
            self._check_memory()
        return outputs

    def _check_memory(self) -> None:
        assert self.memory_limit_mb is not None and self._process is not None
        grown_mb = (_rss_bytes(self._process.pid) - self._rss_start) / 2**20
        if grown_mb > self.memory_limit_mb:
            self._kill()
            self._broken = self.failure(
                PlantDied,
                "the plant exceeded its memory limit",
                f"its process grew by {grown_mb:.0f} MB since the FMU was loaded "
                f"(memory_limit_mb = {self.memory_limit_mb:g}); the FMU leaks memory",
                "its process was stopped" + ("; the next reset() starts a fresh one" if self.restart else ""),
                step=self.sample,
            )
            raise self._broken

    def set_values(self, values: Mapping[str, Any]) -> None:
        self._call(("set", dict(values)), step=self.sample)

    def start_from(self, file: StateFile | None, source: str) -> None:
        """The child starts every episode from the next reset on at ``file``'s saved state (None:
        as the description says); a restarted child is given it again."""
        if self._conn is not None and self._broken is None:
            self._call(("start", file, source), step=None)
        self._start_file = (file, source) if file is not None else None

    @property
    def unusable(self) -> str | None:
        if self._broken is not None:
            return str(self._broken)
        process = self._process
        ended = _ended(process.pid) if process is not None and process.pid else None
        if ended is not None:  # ended between calls, none noticed yet (asked from any thread)
            then = "the next reset() starts a fresh one" if self.restart else "restart the node"
            return f"{self.name}: its process {ended}; {then}"
        return self._unusable

    _unusable: str | None = None  # the child's own model failed to initialise
    _initialised = False  # the child has initialised the FMU once (its first reset answered)
    _first_reset_s = 0.0  # how long that took

    def provenance(self) -> dict[str, str]:
        from bridge.fmu import sha256

        return {"fmu": str(self.fmu_path), "fmu_sha256": sha256(self.fmu_path), "node": ""}

    # -- messages ----------------------------------------------------------------------------------------
    def _call(
        self, message: tuple[Any, ...], *, step: int | None, timeout_s: float | None = None
    ) -> FloatArray:
        if self._conn is None:
            raise self._died(step)
        try:
            self._conn.send(message)
        except OSError:
            raise self._died(step) from None
        return self._answer(timeout_s or self.timeout_s, step)

    def _answer(self, timeout_s: float, step: int | None) -> FloatArray:
        conn = self._conn
        assert conn is not None
        try:
            ready = conn.poll(timeout_s)
            reply = conn.recv() if ready else None
        except (EOFError, OSError):
            raise self._died(step) from None
        if reply is None:
            raise self._hung(step, timeout_s)
        kind, *rest = reply
        if kind == "ok":
            outputs, self._time_s, self.terminated = rest
            return outputs  # type: ignore[no-any-return]
        if kind == "memory":
            self._kill()
            self._broken = self.failure(
                PlantDied,
                "the plant exceeded its memory limit",
                f"an allocation beyond memory_limit_mb = {self.memory_limit_mb:g} failed ({rest[0]})",
                "its process was stopped" + ("; the next reset() starts a fresh one" if self.restart else ""),
                step=step,
            )
            raise self._broken
        if kind == "step_error":  # the child plant's words (what failed, how to fix), this plant's name
            detail, log, self._time_s, what, hint, time_s = rest
            what, hint = what or MODEL_FAILED, hint or MODEL_FAILED_HINT
            raise self.failure(StepError, what, detail, hint, step=step, time_s=time_s, log=log)
        raise rest[0]  # a BridgeError from the child (bad values, config): the plant lives on

    def _hung(self, step: int | None, timeout_s: float) -> StepTimeout:
        self._kill()
        error = self.failure(
            StepTimeout,
            f"no answer within {timeout_s:g} s",
            "the FMU is stuck in a call, or slower than that; its process was stopped",
            "if the model is just slow, raise the deadline: model.isolation.timeout in the "
            "experiment (timeout_s in Python)"
            + ("; the next reset() starts a fresh process" if self.restart else ""),
            step=step,
            time_s=None,
        )
        self._broken = error
        return error

    def _died(self, step: int | None) -> PlantDied:
        process = self._process
        code = None
        if process is not None:
            process.join(timeout=2.0)
            code = process.exitcode
        self._kill()
        if code is not None and code < 0:
            cause = f"its process was killed by {signal.Signals(-code).name}"
            hint = "the FMU crashed (a segfault or an abort in its native code)"
        else:
            cause = f"its process exited with code {code}"
            hint = "the FMU ended the process it runs in (exit() in its native code)"
        if self.memory_limit_mb is not None:
            hint += (
                f"; or an allocation failed at the memory limit (memory_limit_mb = {self.memory_limit_mb:g} "
                "caps the process's address space)"
            )
        if self.restart:
            hint += "; the next reset() starts a fresh process"
        error = self.failure(PlantDied, "the plant died", cause, hint, step=step, time_s=None)
        self._broken = error
        return error

    def _kill(self) -> None:
        process, conn = self._process, self._conn
        self._process = self._conn = None
        if process is not None:
            _kill_group(process)
            process.join(timeout=5.0)
        if conn is not None:
            conn.close()


# -- the child process -------------------------------------------------------------------------------------
def _serve(
    conn: Connection,
    spec: PlantSpec,
    input_names: Sequence[str],
    output_names: Sequence[str],
    memory_limit_mb: float | None = None,
) -> None:
    """The child's loop: one LocalFmuPlant of ``spec``, one message in, one reply out."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the parent, which stops us
    os.setpgid(0, 0)  # a process group of its own: the parent kills it whole, with whatever the FMU forked
    _follow_parent(os.getppid())
    from bridge.errors import BridgeError
    from bridge.plant.local import LocalFmuPlant

    try:
        plant = LocalFmuPlant(spec)
        plant.bind(input_names, output_names)
    except BridgeError as exc:  # the FMU did not load: the parent's "hello" gets the error itself
        _refuse(conn, exc)
        return
    if memory_limit_mb is not None:
        _cap_address_space(memory_limit_mb)
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            break
        op = message[0]
        if op == "close":
            break
        try:
            conn.send(_handle(plant, op, message[1:]))
        except StepError as exc:
            conn.send(("step_error", exc.detail, exc.log, plant.time_s, exc.what, exc.hint, exc.time_s))
        except BridgeError as exc:
            conn.send(("error", exc))
        except MemoryError as exc:
            conn.send(("memory", f"MemoryError in {op}: {exc}"))
            break
    plant.close()


def _refuse(conn: Connection, exc: BridgeError) -> None:
    """Answer the parent's first message with ``exc`` (raised there as it would be in process)."""
    with contextlib.suppress(EOFError, OSError):
        conn.recv()
        conn.send(("error", exc))


def _handle(plant: Any, op: str, args: tuple[Any, ...]) -> tuple[Any, ...]:
    if op == "step":
        outputs = plant.step(args[0])
    elif op == "reset":
        outputs = plant.reset(args[0], args[1])
    elif op == "set":
        plant.set_values(args[0])
        outputs = np.zeros(0)
    elif op == "start":
        plant.start_from(args[0], args[1])
        outputs = np.zeros(0)
    else:  # "hello"
        outputs = np.zeros(0)
    return ("ok", outputs, plant.time_s, plant.terminated)


def _configured_info(spec: PlantSpec) -> ModelInfo:
    """The model the child serves, read here: the FMU's variables, arrays sized as the
    description's structural parameters size them (what the child's model reports)."""
    info = read_model_info(spec.model.fmu)
    values = dict(spec.model.structural_parameters)
    if not values:
        return info
    checked = structure.check(info, values, "structural_parameters")
    return structure.resized(info, structure.sizes_of(checked))


def _start_hint() -> str:
    """Why a child can die before it answers: a program read from standard input cannot be
    imported again by a spawned child; otherwise the FMU's library crashed while loading."""
    main_file = getattr(sys.modules.get("__main__"), "__file__", None)
    if main_file is None or not os.path.isfile(main_file):
        return (
            "its error is printed above. Run from a script file or a module: a child process "
            "imports the main module again, which a program read from standard input cannot be"
        )
    return "the FMU crashed while loading (its native code); its own output, if any, is printed above"


def _kill_group(process: Any) -> None:
    """SIGKILL the child's process group (the child leads it) and so whatever the FMU forked."""
    if process.pid is None:
        return
    try:
        os.killpg(process.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):  # gone, or not yet its own group
        if process.is_alive():
            process.kill()


def _follow_parent(parent: int) -> None:
    """Kill this process group when the parent is gone (killed, or ended without close())."""
    import threading
    import time

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="follow-parent", daemon=True).start()


def _cap_address_space(limit_mb: float) -> None:
    """Cap the address space at its size now (the FMU loaded) plus twice ``limit_mb`` and 64 MB.

    A huge allocation fails at once; a slow leak still meets the sampled resident-memory check
    first, whose message says what happened (address space is not all resident, hence the slack).
    """
    import resource

    now = _vm_bytes(os.getpid())
    if now <= 0:
        return
    cap = now + int((2 * limit_mb + 64) * 2**20)
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))


def _ended(pid: int) -> str | None:
    """How child ``pid`` ended ("was killed by SIGKILL", "exited with code 0"), None while it runs.

    Peeks without reaping it (WNOWAIT): the thread that joins the child still gets its status."""
    try:
        found = os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:  # already reaped: its join has run, or is running
        return None
    if found is None:
        return None
    if found.si_code == os.CLD_EXITED:
        return f"exited with code {found.si_status}"
    return f"was killed by {signal.Signals(found.si_status).name}"


def _vm_bytes(pid: int) -> int:
    """Virtual memory size of process ``pid`` (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/statm") as statm:
            return int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, IndexError, ValueError):
        return 0


def _rss_bytes(pid: int) -> int:
    """Resident memory of process ``pid`` (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, IndexError, ValueError):
        return 0
