"""Shared helpers for the benchmarks: repeated, interleaved timing and a raw FMPy loop."""

from __future__ import annotations

import ctypes
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from bridge.fmu import archive


def median_rate(fn: Callable[[int], None], steps: int, repeats: int) -> tuple[float, list[float]]:
    """Median steps/s of ``fn(steps)`` over ``repeats`` runs (after one warm-up run)."""
    fn(min(steps, 1000))
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(steps)
        rates.append(steps / (time.perf_counter() - start))
    return statistics.median(rates), rates


def interleaved(
    named: dict[str, Callable[[int], None]],
    steps: int,
    repeats: int,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, float]:
    """Median steps/s of each candidate, measured in alternation so machine noise hits all alike.

    ``clock=time.thread_time`` counts this thread's CPU time only: on a shared machine, time
    spent waiting for a core then weighs on no candidate (for loops that run wholly in this
    thread; anything that waits on another process needs the wall clock, the default).
    """
    for fn in named.values():
        fn(min(steps, 1000))
    rates: dict[str, list[float]] = {name: [] for name in named}
    for _ in range(repeats):
        for name, fn in named.items():
            start = clock()
            fn(steps)
            rates[name].append(steps / (clock() - start))
    return {name: statistics.median(values) for name, values in rates.items()}


class RawFmpyLoop:
    """The loop a user writes with FMPy alone: setReal, doStep, getReal per step."""

    def __init__(
        self,
        fmu_path: Path,
        inputs: list[str],
        outputs: list[str],
        step_size_s: float,
        start: dict[str, Any] | None = None,
    ) -> None:
        md = read_model_description(str(fmu_path))
        refs = {v.name: v.valueReference for v in md.modelVariables}
        self._unzip = archive.acquire(fmu_path)
        self.fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=str(self._unzip),
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="raw",
        )
        self.fmu.instantiate()
        self._start = start or {}
        self._in = [refs[n] for n in inputs]
        self._out = [refs[n] for n in outputs]
        self._refs = refs
        self.h = step_size_s
        self.t = 0.0
        self.initialize()

    def initialize(self) -> None:
        fmu = self.fmu
        for name, value in self._start.items():
            fmu.setReal([self._refs[name]], [value])
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        self.t = 0.0

    def reset(self) -> None:
        self.fmu.reset()
        self.initialize()

    def restart(self, state: Any, inputs: list[float]) -> Any:
        """Back to a saved state as an RL loop's reset must be: the state restored, the initial
        inputs written, the first outputs read into the observation array a policy takes."""
        fmu = self.fmu
        fmu.setFMUstate(state)
        self.t = 0.0
        fmu.setReal(self._in, inputs)
        return np.array(fmu.getReal(self._out), dtype=np.float32)

    def restart_direct(self, state: Any, inputs: list[float]) -> Any:
        """:meth:`restart` with FMPy's checked wrappers left out: the FMU's own three functions
        called through ctypes with arguments built beforehand (:meth:`prepare_direct`), the outputs
        copied into an observation. The least a Python reset that returns an observation does."""
        (set_state, set_real, get_real), (vin, nin, u, vout, nout, y) = self._functions, self._direct
        c = self.fmu.component
        set_state(c, state)
        self.t = 0.0
        u[:] = inputs
        set_real(c, vin, nin, u)
        get_real(c, vout, nout, y)
        return np.array(y, dtype=np.float32)

    def prepare_direct(self) -> None:
        n_in, n_out = len(self._in), len(self._out)
        functions = self.fmu._functions  # FMPy's ctypes functions, under its logging wrapper
        self._functions = tuple(functions[f"fmi2{name}"] for name in ("SetFMUstate", "SetReal", "GetReal"))
        self._direct = (
            (ctypes.c_uint * n_in)(*self._in),
            n_in,
            (ctypes.c_double * n_in)(),
            (ctypes.c_uint * n_out)(*self._out),
            n_out,
            (ctypes.c_double * n_out)(),
        )

    def run(self, steps: int, action: Callable[[list[float]], list[float]] | None = None) -> None:
        fmu, h, vin, vout = self.fmu, self.h, self._in, self._out
        t = self.t
        y = fmu.getReal(vout)
        for _ in range(steps):
            u = action(y) if action else [0.5]
            fmu.setReal(vin, u)
            fmu.doStep(t, h)
            t += h
            y = fmu.getReal(vout)
            if abs(y[0]) > 1e6:  # keep the work comparable to an env's termination check
                break
        self.t = t

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def table(rows: list[tuple[str, ...]], header: tuple[str, ...]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |"
    sep = "|-" + "-|-".join("-" * w for w in widths) + "-|"
    body = ["| " + " | ".join(str(c).ljust(w) for c, w in zip(r, widths)) + " |" for r in rows]
    return "\n".join([line, sep, *body])


def fmt_us(rate: float) -> str:
    return f"{1e6 / rate:.2f}"


np.set_printoptions(precision=4)
