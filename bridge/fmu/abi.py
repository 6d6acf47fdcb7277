"""The C side's vocabulary: FMI status codes, the native helpers' result codes and struct mirrors.

One module, so that a field added to a struct in ``batch.c`` or ``fixed_step.c`` has one Python
mirror to follow, and so that status codes have one spelling. Nothing outside ``bridge.fmu``
imports it (pyproject.toml's import contracts say so; ``lint-imports`` checks it in CI): above
this package, outcomes are booleans and exceptions, never FMI statuses.
"""

from __future__ import annotations

import ctypes
from typing import Any, Final

# -- FMI statuses (fmi2Status / fmi3Status; FMI 1.0 uses the same numbers) -------------------------
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
STATUS_NAMES: Final = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")

# -- batch.c: a sample's outcome per instance (an FMI status, or one of these) ----------------------
TERMINATED: Final = 5  # the FMU asked to stop (FMI 2.0: Discard with fmi2Terminated)
SET_FAILED: Final = 16  # + the status of the failed set
GET_FAILED: Final = 32  # + the status of the failed get
INACTIVE: Final = -1  # the instance was not stepped
NONFINITE: Final = 64  # master.c: an input its signal group refuses (NaN, inf, not whole, out of range, ...)
SETTLING: Final = 128  # master.c: added to the status of a failure while settling (not stepping)
STATE: Final = 256  # master.c: + the status of a failed get or set of an FMU state (iteration)

# -- fixed_step.c: why the integration loop returned ---------------------------------------------------
END, STATE_EVENT, TIME_EVENT, STEP_EVENT, TERMINATE = 0, 1, 2, 3, 4
FAILED: Final = 64  # + 16 * the failing function's index + its status


def status_name(status: int) -> str:
    """``"Error"`` for 3; statuses above Pending (the helpers' own codes) read as Pending."""
    return STATUS_NAMES[min(max(status, 0), len(STATUS_NAMES) - 1)]


def address(fn: Any) -> int:
    """The address of a ctypes function (0 for None): what the C helpers call through."""
    return int(ctypes.cast(fn, ctypes.c_void_p).value or 0) if fn is not None else 0


def pointer_value(handle: Any) -> int:
    """The integer value of an FMU component (or any) pointer, 0 for NULL."""
    return int(ctypes.cast(handle, ctypes.c_void_p).value or 0)


class BatchSpec(ctypes.Structure):
    """``batch.c``'s ``BatchSpec``: which FMI functions, which value references, the time grid."""

    _fields_ = [
        ("major", ctypes.c_int),
        ("set_real", ctypes.c_void_p),
        ("get_real", ctypes.c_void_p),
        ("do_step", ctypes.c_void_p),
        ("bool_status", ctypes.c_void_p),
        ("n_in", ctypes.c_int),
        ("in_vr", ctypes.c_void_p),
        ("n_out", ctypes.c_int),
        ("out_vr", ctypes.c_void_p),
        ("t0", ctypes.c_double),
        ("h", ctypes.c_double),
        ("steps", ctypes.c_int),
        ("nv_in", ctypes.c_int),  # values (arrays count every element); n_in counts value references
        ("nv_out", ctypes.c_int),
    ]


class FixedSpec(ctypes.Structure):
    """``fixed_step.c``'s ``FixedSpec``: FMI version, method, sizes, function addresses, work array."""

    _fields_ = [
        ("major", ctypes.c_int),
        ("method", ctypes.c_int),
        ("nx", ctypes.c_int),
        ("nz", ctypes.c_int),
        ("completed", ctypes.c_int),
        *((name, ctypes.c_void_p) for name in ("set_time", "set_x", "get_x", "get_dx", "get_z", "step")),
        ("work", ctypes.c_void_p),
    ]


class FixedCall(ctypes.Structure):
    """``fixed_step.c``'s ``FixedCall``: one call's instance, times and announced time event (NaN: none)."""

    _fields_ = [
        ("component", ctypes.c_void_p),
        ("time", ctypes.c_double),
        ("origin", ctypes.c_double),
        ("substep", ctypes.c_double),
        ("total", ctypes.c_longlong),
        ("end", ctypes.c_double),
        ("next_event", ctypes.c_double),
        ("announced", ctypes.c_double),
    ]


class FixedBatchSpec(ctypes.Structure):
    """``fixed_step.c``'s ``FixedBatch``: FMI version, Float64 set/get, value references, the time grid."""

    _fields_ = [
        ("major", ctypes.c_int),
        ("set_real", ctypes.c_void_p),
        ("get_real", ctypes.c_void_p),
        ("n_in", ctypes.c_int),
        ("in_vr", ctypes.c_void_p),
        ("n_out", ctypes.c_int),
        ("out_vr", ctypes.c_void_p),
        ("t0", ctypes.c_double),
        ("h", ctypes.c_double),
        ("steps", ctypes.c_int),
        ("substeps", ctypes.c_int),
        ("nv_in", ctypes.c_int),  # values (arrays count every element); n_in counts value references
        ("nv_out", ctypes.c_int),
    ]


class MasterComponent(ctypes.Structure):
    """``master.c``'s ``Component``: one component's functions, signals, grid and step counter."""

    _fields_ = [
        ("major", ctypes.c_int),
        ("set_real", ctypes.c_void_p),
        ("get_real", ctypes.c_void_p),
        ("do_step", ctypes.c_void_p),
        ("bool_status", ctypes.c_void_p),
        ("component", ctypes.c_void_p),
        ("n_in", ctypes.c_int),
        ("in_vr", ctypes.c_void_p),
        ("u", ctypes.c_void_p),
        ("n_out", ctypes.c_int),
        ("out_vr", ctypes.c_void_p),
        ("y", ctypes.c_void_p),
        ("t0", ctypes.c_double),
        ("h", ctypes.c_double),
        ("steps", ctypes.c_int),
        ("k", ctypes.c_void_p),  # long long*: the model's own clock
        ("nv_in", ctypes.c_int),  # values of u (arrays count every element); n_in counts value references
        ("nv_out", ctypes.c_int),
        ("get_state", ctypes.c_void_p),  # fixed-point iteration: the FMU state functions
        ("set_state", ctypes.c_void_p),
        ("free_state", ctypes.c_void_p),
        ("used", ctypes.c_void_p),  # double*: the inputs of the last pass (nv_in values)
        ("n_in_blocks", ctypes.c_int),  # 0: u is one Float64 buffer; else typed blocks (MasterBlock)
        ("in_blocks", ctypes.c_void_p),
        ("n_out_blocks", ctypes.c_int),
        ("out_blocks", ctypes.c_void_p),
    ]


BLOCK_KINDS: Final = {
    name: code
    for code, name in enumerate(
        ("float64", "float32", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64")
    )
}
"""``master.c``'s Block kinds by numpy dtype name; booleans have their own two (below)."""
BOOL_INT: Final = 10  # FMI 2.0 fmi2Boolean (an int)
BOOL_BYTE: Final = 11  # FMI 3.0 fmi3Boolean (a C bool)


class MasterBlock(ctypes.Structure):
    """``master.c``'s ``Block``: the variables of one FMI type in a component's inputs or outputs,
    with their typed buffer, their positions in the float64 vector and their checks."""

    _fields_ = [
        ("kind", ctypes.c_int),
        ("set", ctypes.c_void_p),
        ("get", ctypes.c_void_p),
        ("vr", ctypes.c_void_p),
        ("n_vr", ctypes.c_int),
        ("buf", ctypes.c_void_p),
        ("nv", ctypes.c_int),
        ("n_el", ctypes.c_int),
        ("pos", ctypes.c_void_p),  # int[n_el]: index in u or y
        ("at", ctypes.c_void_p),  # int[n_el]: index in buf
        ("partial", ctypes.c_int),
        ("enum_first", ctypes.c_void_p),  # int[n_el]: first allowed value in items, -1: any
        ("enum_count", ctypes.c_void_p),
        ("items", ctypes.c_void_p),  # double[]
    ]


class MasterIteration(ctypes.Structure):
    """``master.c``'s ``Iteration``: fixed-point iteration of each macro step (max_iterations > 1)."""

    _fields_ = [
        ("max_iterations", ctypes.c_int),
        ("tolerance", ctypes.c_double),
        ("last", ctypes.c_int),  # passes made in the last macro step
        ("unconverged", ctypes.c_int),  # macro steps that did not converge, added up
        ("states", ctypes.c_void_p),  # void*[n]
        ("saved_k", ctypes.c_void_p),  # long long[n]
    ]


class MasterLink(ctypes.Structure):
    """``master.c``'s ``Link``: output ``i`` of component ``source`` feeds input ``j`` of ``target``,
    as it is or (``affine`` 1) as ``factor * value + offset``."""

    _fields_ = [
        ("source", ctypes.c_int),
        ("i", ctypes.c_int),
        ("target", ctypes.c_int),
        ("j", ctypes.c_int),
        ("factor", ctypes.c_double),
        ("offset", ctypes.c_double),
        ("affine", ctypes.c_int),
    ]


class MasterSample(ctypes.Structure):
    """``master.c``'s ``Sample``: a system's components and links, the task's inputs scattered into
    them and its observation gathered out of them, in one call (``master_sample``)."""

    _fields_ = [
        ("comps", ctypes.c_void_p),
        ("n", ctypes.c_int),
        ("links", ctypes.c_void_p),
        ("n_links", ctypes.c_int),
        ("gauss_seidel", ctypes.c_int),
        ("status", ctypes.c_void_p),
        ("n_ext", ctypes.c_int),
        ("ext_comp", ctypes.c_void_p),
        ("ext_j", ctypes.c_void_p),
        ("ext", ctypes.c_void_p),
        ("n_obs", ctypes.c_int),
        ("obs_comp", ctypes.c_void_p),
        ("obs_i", ctypes.c_void_p),
        ("obs", ctypes.c_void_p),
        ("done", ctypes.c_int),
        ("stopped", ctypes.c_int),
        ("n_settle", ctypes.c_int),
        ("settle", ctypes.c_void_p),
        ("iteration", MasterIteration),
    ]


Clock = ctypes.c_longlong
"""A model's step counter ``k``: one C ``long long`` that native steppers advance in place."""
