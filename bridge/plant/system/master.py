"""The master: fixed-step Jacobi and Gauss-Seidel over component plants.

Every component is a :class:`~bridge.plant.base.Plant` whose sample is one macro step ``H``
(in this process, ``n`` FMU steps of its own size: multi-rate), bound to all its connected and
external inputs and all the outputs anyone reads. A macro step from ``t`` to ``t + H``:

* **Jacobi**: every component gets the values its sources held at ``t``, all are sent their
  inputs before any answer is awaited (components in nodes step in parallel), then the outputs
  at ``t + H`` are exchanged.
* **Gauss-Seidel**: components step one after another in the graph's order; each gets the
  outputs at ``t + H`` of the components before it, and at ``t`` of the others.

With ``max_iterations > 1`` each macro step is repeated, the components rolled back to ``t``,
with the connected inputs set to the outputs at ``t + H`` of the previous pass, until those
inputs change by at most ``tolerance`` (relative): the coupling becomes implicit, which solves
algebraic loops. Components in this process save and restore their FMU state directly;
components in nodes carry the save and the restore on their next action (no extra round trip).
Initialisation resets the components in :func:`graph.init_order` so that connected values reach
each component before it starts.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bridge.errors import ConfigError
from bridge.plant.base import FloatArray, Plant
from bridge.plant.system.description import SystemDescription

if TYPE_CHECKING:
    from bridge.plant.system.native_master import NativeMaster

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Link:
    """One connection as array positions: ``outputs[source][i] -> inputs[target][j]``, through
    ``convert`` (unit conversion and SSP transformation) where the connection has one."""

    source: str
    i: int
    target: str
    j: int
    convert: Callable[[float], float] | None = None


class Master:
    """Steps ``plants`` (one per component, already bound) as the system ``system`` says."""

    def __init__(
        self,
        system: SystemDescription,
        plants: Mapping[str, Plant],
        links: Sequence[Link],
        order: Sequence[str],
        init_order: Sequence[str],
        *,
        settle: Sequence[str] = (),
    ) -> None:
        self.system, self.plants, self.links = system, dict(plants), list(links)
        self.order, self.init_order = list(order), list(init_order)
        self.iterations = system.max_iterations
        if self.iterations > 1:
            _check_rollback(system, plants)
        updated = system.feedthrough_outputs == "updated"
        self.settle_order = [n for n in self.init_order if n in set(settle)] if updated else []
        _check_settle(system, plants, self.settle_order)
        self.inputs = {n: np.array([0.0] * len(p.input_names)) for n, p in plants.items()}
        self.outputs = {n: np.zeros(len(p.output_names)) for n, p in plants.items()}
        self._into: dict[str, list[Link]] = {n: [] for n in plants}
        for link in self.links:
            self._into[link.target].append(link)
        self.last_iterations = 0
        self.unconverged_steps = 0
        self.init_converged = True
        self.native: NativeMaster | None = None
        # the task's inputs and observed outputs, (component, position): the native sample sets
        # and gathers them in its call (set by the owner before the first initialisation)
        self.external: list[tuple[str, int]] = []
        self.observed: list[tuple[str, int]] = []
        self._native_checked = False

    def _gather(self, name: str, ready: set[str] | None = None) -> FloatArray:
        u = self.inputs[name]
        for link in self._into[name]:
            if ready is None or link.source in ready:
                y = self.outputs[link.source][link.i]
                u[link.j] = y if link.convert is None else link.convert(y)
        return u

    def initialize(self, values: Mapping[str, Mapping[str, Any]], inputs: Mapping[str, FloatArray]) -> None:
        """Reset every component with its ``values`` and ``inputs`` (start values, then the values
        of connected outputs as they become known at ``t0``); then the native macro step, where it
        applies (:mod:`bridge.plant.system.native_master`), takes the new instances."""
        self._initialize(values, inputs)
        if not self._native_checked:
            from bridge.plant.system.native_master import native_master

            self.native, self._native_checked = native_master(self), True
        if self.native is not None:
            self.native.refresh()

    def _initialize(self, values: Mapping[str, Mapping[str, Any]], inputs: Mapping[str, FloatArray]) -> None:
        for name, u in inputs.items():
            self.inputs[name] = np.array(u, dtype=np.float64)
        ready: set[str] = set()
        used: dict[str, FloatArray] = {}  # the inputs each component was last started with
        for name in self.init_order:
            used[name] = u = self._gather(name, ready).copy()
            self.outputs[name] = np.asarray(self.plants[name].reset(values.get(name, {}), u.tolist()))
            ready.add(name)
        self.init_converged = True
        for _ in range(self.iterations - 1):  # an algebraic loop at t0: restart until consistent
            if self._close(used, {n: self._gather(n).copy() for n in used}):
                return
            for name in self.init_order:
                u = self._gather(name)
                if not np.array_equal(u, used[name]):
                    used[name] = u.copy()
                    self.outputs[name] = np.asarray(self.plants[name].reset(values.get(name, {}), u.tolist()))
        if self.iterations > 1 and not self._close(used, {n: self._gather(n).copy() for n in used}):
            self.init_converged = False
            _log.warning(
                "system initialisation did not converge in %d sweeps (tolerance %g); raise "
                "system.iteration.max_iterations%s",
                self.iterations,
                self.system.tolerance,
                self.system.where,
            )

    def step(self) -> None:
        """One macro step from ``t`` to ``t + H`` (with fixed-point iteration where configured);
        then, with ``feedthrough_outputs: updated``, the feedthrough components' outputs again
        from the inputs of ``t + H``."""
        if self.native is not None:
            self.native.run(1)
            return
        self._step()
        for name in self.settle_order:  # sources before consumers: values of t + H flow on
            u = self._gather(name)
            self.outputs[name] = self.plants[name].settle(u.tolist())

    def _step(self) -> None:
        if self.iterations <= 1:
            self._pass()
            return
        plants = self.plants
        saved: dict[str, Any] = {}
        try:
            for n, p in plants.items():
                saved[n] = p.save()
            for k in range(1, self.iterations + 1):
                used = self._pass()
                self.last_iterations = k
                if self._close(used, {n: self._gather(n).copy() for n in used}):
                    return
                if k == self.iterations:
                    self.unconverged_steps += 1
                    _log.debug("macro step did not converge in %d iterations", k)
                    return
                for n, p in plants.items():  # back to t; the outputs stay those at t + H
                    p.restore(saved[n])
        finally:
            for n, state in saved.items():
                plants[n].discard(state)

    def _pass(self) -> dict[str, FloatArray]:
        """Step every component once; the inputs each one was given (only when iterating)."""
        used: dict[str, FloatArray] = {}
        plants, outputs = self.plants, self.outputs
        if self.iterations <= 1 and self.system.algorithm == "jacobi":  # the hot path
            for name in self.order:
                plants[name].send(self._gather(name).tolist())
            for name in self.order:
                outputs[name] = plants[name].receive()
            return used
        if self.system.algorithm == "gauss_seidel":
            for name in self.order:
                used[name] = u = self._gather(name).copy()
                self.outputs[name] = self.plants[name].step(u.tolist())
            return used
        for name in self.order:
            used[name] = self._gather(name).copy()
        for name in self.order:
            self.plants[name].send(used[name].tolist())
        for name in self.order:
            self.outputs[name] = self.plants[name].receive()
        return used

    def _close(self, before: Mapping[str, FloatArray], after: Mapping[str, FloatArray]) -> bool:
        tol = self.system.tolerance
        return all(
            bool(np.all(np.abs(after[n] - before[n]) <= tol * (1.0 + np.abs(after[n])))) for n in before
        )


def _check_rollback(system: SystemDescription, plants: Mapping[str, Plant]) -> None:
    """Iteration rolls every component back: each must save and restore its state."""
    cannot = [p for p in plants.values() if not p.can_save]
    if cannot:
        why = "; ".join(f"{p.name} cannot: {p.save_refusal}" for p in cannot)
        raise ConfigError(
            f"system.iteration: fixed-point iteration rolls every component back to the start of the "
            f"macro step, and {why}; remove system.iteration, or use FMUs that can save their state "
            f"(FMI 2.0/3.0 with canGetAndSetFMUstate){system.where}"
        )


def _check_settle(system: SystemDescription, plants: Mapping[str, Plant], names: Sequence[str]) -> None:
    """Updated outputs set inputs between steps: each feedthrough component must be in this process."""
    cannot = [plants[n].name for n in names if not plants[n].can_settle]
    if cannot:
        raise ConfigError(
            f"system.feedthrough_outputs: updated sets the inputs of feedthrough components after the "
            f"exchange and reads their outputs again, which components in nodes cannot do: {cannot}; "
            f"use feedthrough_outputs: held, or run those components in this process{system.where}"
        )
