"""How ``master.c`` sets a component's inputs and gets its outputs: one Float64 call, or typed blocks.

A component whose inputs (or outputs) are all Float64 scalars, or whole FMI 3.0 Float64 arrays in
row-major order, is served straight from the master's float64 array (one ``fmi2SetReal`` /
``fmi3SetFloat64``). Any other signal group (Float32, the integer types, Boolean, Enumeration,
arrays used in part) is passed as its FMI type groups (:meth:`SignalGroup.typed_blocks`): the C code
checks each input as the group would, converts between the float64 array and each type's buffer
and makes the group's own set and get calls, in its order. So both masters make the same FMI calls
with the same values.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import Any

import numpy as np

from bridge.fmu.abi import BLOCK_KINDS, BOOL_BYTE, BOOL_INT, MasterBlock, MasterComponent, address
from bridge.fmu.signals import SignalGroup, TypedBlock

__all__ = ["bind_signals", "servable"]


def servable(inputs: SignalGroup | None, outputs: SignalGroup | None) -> bool:
    """Whether ``master.c`` can set ``inputs`` and get ``outputs`` (either may be None: no signals)."""
    for group, writing in ((inputs, True), (outputs, False)):
        direct = group is None or group.native_buffer(writing=writing) is not None
        if not direct and group is not None and group.typed_blocks(writing=writing) is None:
            return False
    return True


def _ints(values: Sequence[int]) -> np.ndarray[Any, np.dtype[np.intc]]:
    return np.ascontiguousarray(np.array(list(values) or [0], dtype=np.intc))


def _kind(block: TypedBlock) -> int:
    if block.boolean:
        return BOOL_BYTE if block.dtype == "bool" else BOOL_INT
    return BLOCK_KINDS[block.dtype]


def _blocks(typed: list[TypedBlock], keep: list[Any]) -> Any:
    """``typed`` as a ctypes array of ``MasterBlock``; the arrays it points into go into ``keep``."""
    blocks = (MasterBlock * len(typed))()
    for b, t in zip(blocks, typed):
        first: list[int] = []
        count: list[int] = []
        items: list[float] = []
        for allowed in t.allowed:
            first.append(-1 if allowed is None else len(items))
            count.append(0 if allowed is None else len(allowed))
            items += allowed or []
        arrays = [_ints(t.positions), _ints(t.at), _ints(first), _ints(count), np.array(items or [0.0])]
        keep += arrays
        b.kind, b.vr, b.n_vr, b.buf, b.nv = _kind(t), t.vrs, t.n_vrs, t.buffer, t.n_values
        b.set, b.get = address(t.setter), address(t.getter)
        b.n_el, b.partial = len(t.positions), int(t.partial)
        b.pos, b.at, b.enum_first, b.enum_count, b.items = (a.ctypes.data for a in arrays)
    return blocks


def bind_signals(
    c: MasterComponent, inputs: SignalGroup | None, outputs: SignalGroup | None, n_in: int, n_out: int
) -> list[Any]:
    """Point ``c``'s input and output fields at ``inputs`` and ``outputs`` (which :func:`servable`
    accepted; ``n_in`` and ``n_out`` values in the master's arrays); returns what must stay alive
    while ``c`` is used."""
    keep: list[Any] = []
    c.in_vr, c.n_in, c.nv_in, c.n_in_blocks, c.in_blocks = _side(inputs, True, n_in, keep)
    c.out_vr, c.n_out, c.nv_out, c.n_out_blocks, c.out_blocks = _side(outputs, False, n_out, keep)
    return keep


def _side(
    group: SignalGroup | None, writing: bool, n_values: int, keep: list[Any]
) -> tuple[Any, int, int, int, int | None]:
    """One side's fields (value references, their count, values in the master's array, typed
    blocks and their address): a direct Float64 buffer, typed blocks, or nothing."""
    if group is None:
        return None, 0, 0, 0, None
    direct = group.native_buffer(writing=writing)
    if direct is not None:
        vrs, n, nv, _ = direct
        return vrs, n, nv, 0, None
    blocks = _blocks(group.typed_blocks(writing=writing) or [], keep)
    keep.append(blocks)
    return None, 0, n_values, len(blocks), ctypes.addressof(blocks)
