"""Batched, typed reads and writes of a fixed list of numeric variables.

A :class:`SignalGroup` presents any mix of Float/Int/Boolean/Enumeration variables as one
float64 vector, but talks to the FMU with one call per FMI type group into preallocated,
correctly typed buffers: integers and booleans are never read through getReal.
"""

from __future__ import annotations

import ctypes
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from bridge.errors import FmuError, VariableError
from bridge.fmu.abi import STATUS_NAMES, WARNING
from bridge.fmu.backend import numpy_dtype
from bridge.fmu.values import int_range

if TYPE_CHECKING:
    from bridge.fmu.description import Variable
    from bridge.fmu.model import Model

FloatArray = npt.NDArray[np.float64]
_FLOAT, _INT, _BOOL = 0, 1, 2


class _Block:
    """Variables of one FMI type: one get and one set call per sample."""

    __slots__ = (
        "_vrs",
        "buf",
        "enums",
        "exact",
        "get",
        "index",
        "kind",
        "n",
        "names",
        "nargs",
        "pick",
        "ptr",
        "ranges",
        "set",
        "variables",
        "vrs",
    )
    # ``vrs`` and ``ptr`` are integer addresses of ``_vrs`` and ``buf``, which the block keeps alive.

    def __init__(self, model: Model, elements: list[tuple[Variable, int | None]], index: list[int]) -> None:
        backend = model.backend
        variables = [var for var, _ in elements]
        ctype = backend.ctype(variables[0].type)
        self.variables = variables
        self.names = [var.element_names()[i] if i is not None else var.name for var, i in elements]
        self.index = np.asarray(index, dtype=np.intp)
        unique = list(dict.fromkeys(variables))
        self.n = len(unique)
        self._vrs = (ctypes.c_uint * self.n)(*(v.value_reference for v in unique))
        self.vrs = ctypes.addressof(self._vrs)
        # FMI 3.0 arrays are read and written whole; ``pick`` takes the elements of the group.
        offsets = dict(zip(unique, itertools.accumulate((v.size for v in unique), initial=0)))
        positions = [offsets[var] + (i or 0) for var, i in elements]
        total = sum(v.size for v in unique)
        self.pick = None if positions == list(range(total)) else np.asarray(positions, dtype=np.intp)
        self.buf = np.zeros(total, dtype=numpy_dtype(ctype))
        self.ptr = self.buf.ctypes.data
        self.get = backend.fast_accessor(variables[0].type, setter=False)
        self.set = backend.fast_accessor(variables[0].type, setter=True) if _settable(variables) else None
        # FMI 3.0 getters/setters take the number of values (arrays expanded) as a fifth argument.
        self.nargs = (total,) if backend.major == 3 else ()
        kind = variables[0].type
        self.kind = _FLOAT if kind.startswith("Float") else _BOOL if kind == "Boolean" else _INT
        # 64-bit integers are checked and written as Python ints: float64 cannot hold them exactly.
        self.exact = self.kind == _INT and self.buf.dtype.itemsize == 8
        self.ranges = [int_range(v.type, backend.major) for v in variables] if self.kind == _INT else []
        # Enumerations accept only their declared item values.
        self.enums = [
            (i, np.array([value for _, value in v.enum_items], dtype=np.float64))
            for i, v in enumerate(variables)
            if v.enum_items
        ]


@dataclass(frozen=True)
class TypedBlock:
    """One FMI type of a signal group, for a native loop: element ``e`` of the group's float64
    vector at ``positions[e]`` is ``buffer[at[e]]``, checked against ``allowed[e]`` (enumeration
    items, None: any value of the type); ``partial``: an array used in part, read before it is set."""

    dtype: str
    boolean: bool
    setter: Any  # the typed set (None: reading)
    getter: Any  # the typed get
    vrs: int
    n_vrs: int
    buffer: int
    n_values: int
    positions: list[int]
    at: list[int]
    partial: bool
    allowed: list[list[float] | None]


def _typed(block: _Block, writing: bool) -> TypedBlock:
    at = list(range(len(block.buf))) if block.pick is None else block.pick.tolist()
    allowed: list[list[float] | None] = [None] * len(block.index)
    for i, items in block.enums:
        allowed[i] = items.tolist()
    return TypedBlock(
        dtype=block.buf.dtype.name,
        boolean=block.kind == _BOOL,
        setter=block.set if writing else None,
        getter=block.get,
        vrs=block.vrs,
        n_vrs=block.n,
        buffer=block.ptr,
        n_values=len(block.buf),
        positions=block.index.tolist(),
        at=at,
        partial=block.pick is not None,
        allowed=allowed,
    )


def _settable(variables: list[Variable]) -> bool:
    return all(v.settable_in_step for v in variables)


class SignalGroup:
    """A fixed, ordered list of numeric variables read or written as one float64 vector.

    ``read()`` returns a new array each call; ``read_into(out)`` fills a caller-owned array.
    ``write(values)`` sets all variables of the group (inputs or tunable parameters) with one
    call per type, after checking the values (finite, integral for integer types, in the range of
    the type), so a bad action never reaches the FMU. 64-bit integers are written exactly when
    given as ints. In model exchange, a group with discrete inputs or tunable parameters is
    written in event mode (see :meth:`Model.write_in_event_mode`).
    """

    write: Callable[[npt.ArrayLike], None]

    def __init__(
        self,
        model: Model,
        elements: Sequence[tuple[Variable, int | None]],
        names: Sequence[str] | None = None,
    ) -> None:
        self._model = model
        self._backend = model.backend
        variables = [var for var, _ in elements]
        self.variables = tuple(variables)
        self.names = tuple(names) if names is not None else tuple(v.name for v in variables)
        groups: dict[str, tuple[list[tuple[Variable, int | None]], list[int]]] = {}
        for i, element in enumerate(elements):
            key = model.backend.type_key(element[0].type)
            members, index = groups.setdefault(key, ([], []))
            members.append(element)
            index.append(i)
        self._blocks = [_Block(model, members, index) for members, index in groups.values()]
        self._values = np.zeros(len(variables), dtype=np.float64)
        first = self._blocks[0] if len(self._blocks) == 1 else None
        # The common case (all Float64 scalars) reads straight into the float64 vector.
        self._direct = first is not None and first.buf.dtype == np.float64 and first.pick is None
        if self._direct and first is not None:
            self._values = first.buf
            self._cbuf = (ctypes.c_double * len(first.buf)).from_buffer(first.buf)  # type: ignore[arg-type]
        # Model exchange restarts the integrator where inputs jumped; discrete ones need event mode.
        self._notify = model.interface == "me"
        events = self._notify and any(v.variability != "continuous" for v in variables)
        self.write = self._write_in_event_mode if events else self._write

    def __len__(self) -> int:
        return len(self.names)

    @property
    def writable(self) -> bool:
        return all(b.set is not None for b in self._blocks)

    def read(self) -> FloatArray:
        """Current values as a new float64 array (booleans as 0/1)."""
        if self._direct:  # inlined: this runs once per sample
            block = self._blocks[0]
            component = self._backend.component
            if component is None:
                raise self._no_instance()
            status = block.get(component, block.vrs, block.n, block.ptr, *block.nargs)
            if status > WARNING:
                self._fail("get", block, status)
            got: FloatArray = block.buf.copy()
            return got
        self._fetch()
        values: FloatArray = self._values.copy()
        return values

    def read_into(self, out: FloatArray) -> None:
        """Current values written into ``out`` (float64, same length) without allocating."""
        self._fetch()
        out[:] = self._values

    def _fetch(self) -> None:
        component = self._backend.component
        if component is None:
            raise self._no_instance()
        for block in self._blocks:
            status = block.get(component, block.vrs, block.n, block.ptr, *block.nargs)
            if status > WARNING:
                self._fail("get", block, status)
            if not self._direct:
                self._values[block.index] = block.buf if block.pick is None else block.buf[block.pick]

    def _write_in_event_mode(self, values: npt.ArrayLike) -> None:
        self._model.write_in_event_mode(lambda: self._write(values))

    def _write(self, values: npt.ArrayLike) -> None:
        component = self._backend.component
        if component is None:
            raise self._no_instance()
        if self._direct:
            self._write_direct(component, values)
            return
        vec = np.asarray(values, dtype=np.float64)
        if vec.shape != (len(self.names),):
            raise self._shape_error(values)
        for block in self._blocks:
            part: Any = _exact_part(values, block) if block.exact else vec[block.index]
            if not _valid(part, block):
                raise self._value_error(part, block)
            if block.set is None:
                raise self._not_settable()
            if block.pick is None:
                block.buf[:] = part
            else:  # arrays are written whole: the other elements keep their current values
                status = block.get(component, block.vrs, block.n, block.ptr, *block.nargs)
                if status > WARNING:
                    self._fail("get", block, status)
                block.buf[block.pick] = part
            status = block.set(component, block.vrs, block.n, block.ptr, *block.nargs)
            if status > WARNING:
                self._fail("set", block, status)
        if self._notify:
            self._model.inputs_written()

    def native_buffer(self, *, writing: bool) -> tuple[int, int, int, int] | None:
        """(value-reference array address, value references, values, float64 buffer address) of
        an all-Float64 group, for a native stepper that sets (``writing``) or gets the group
        itself; None for other groups (mixed types, some elements of an array or out of row-major
        order, not settable during a step, model exchange). An FMI 3.0 array is one value
        reference and all its elements: the stepper passes the values as ``nValues``."""
        block = self._blocks[0]
        if not self._direct or self._notify or (writing and block.set is None):
            return None
        return block.vrs, block.n, len(block.buf), block.ptr

    def typed_blocks(self, *, writing: bool) -> list[TypedBlock] | None:
        """The group's FMI type groups as a native loop converts them (``master.c``'s Block), in
        the order :meth:`write` and :meth:`read` call them; None where a native loop cannot
        (model exchange, or, ``writing``, a variable not settable during a step)."""
        if self._notify or (writing and any(b.set is None for b in self._blocks)):
            return None
        return [_typed(block, writing) for block in self._blocks]

    def float64_layout(self) -> tuple[list[int], int] | None:
        """(value references, values) of an all-Float64 group of whole variables in row-major
        order (what a batch loop passes to the FMU), else None."""
        if not self._direct:
            return None
        block = self._blocks[0]
        return list(block._vrs), len(block.buf)

    def stage(self, values: Any) -> None:
        """Check ``values`` (finite, one per variable) and place them in the group's buffer
        without calling the FMU: the native stepper passes that buffer to the setter. All-Float64
        groups only (see :meth:`native_buffer`); plain-Python checks beat numpy for a few values."""
        try:
            for v in values:
                if v - v != 0.0:  # NaN or infinity
                    raise self._value_error(np.asarray(values, dtype=np.float64).reshape(-1), self._blocks[0])
            self._cbuf[:] = values
        except (TypeError, ValueError) as exc:
            if isinstance(exc, VariableError):
                raise
            flat = np.asarray(values, dtype=np.float64).reshape(-1)
            if flat.shape != (len(self._blocks[0].buf),):
                raise self._shape_error(values) from exc
            self.stage(flat.tolist())

    def latest(self) -> FloatArray:
        """A copy of the values a native stepper last read into the buffer (all-Float64 groups)."""
        latest: FloatArray = self._blocks[0].buf.copy()
        return latest

    def _write_direct(self, component: Any, values: Any) -> None:
        """All-Float64 groups (the common case)."""
        block = self._blocks[0]
        if block.set is None:
            raise self._not_settable()
        self.stage(values)
        status = block.set(component, block.vrs, block.n, block.ptr, *block.nargs)
        if status > WARNING:
            self._fail("set", block, status)
        if self._notify:
            self._model.inputs_written()

    def _no_instance(self) -> FmuError:
        return FmuError(
            f"{self._model.info.model_name}: no FMU instance: the model is closed or was never initialised"
        )

    def _where(self) -> str:
        return f"at step {self._model.step_index} (t={self._model.time_s:g} s)"

    def _shape_error(self, values: Any) -> VariableError:
        shape = np.shape(values)
        return VariableError(
            f"{self._model.info.model_name}: expected {len(self.names)} values for {list(self.names)}, "
            f"got an array of shape {shape}"
        )

    def _value_error(self, part: Any, block: _Block) -> VariableError:
        bad = [
            f"{name}={_show(value)}" + _declared(i, block)
            for i, (value, name) in enumerate(zip(part, block.names))
            if not _valid_one(value, i, block) or _bad_enum(value, i, block)
        ]
        expected = {_FLOAT: "finite numbers", _INT: "whole numbers in range", _BOOL: "0 or 1"}[block.kind]
        finite = all(not isinstance(v, float) or math.isfinite(v) for v in np.asarray(part).tolist())
        hint = (
            "round, clip or map the value before writing it"
            if finite
            else "a NaN or inf usually comes from a diverged policy or controller"
        )
        return VariableError(
            f"{self._model.info.model_name}: invalid value {', '.join(bad)} {self._where()}: expected "
            f"{expected}; {hint}"
        )

    def _not_settable(self) -> VariableError:
        fixed = [n for b in self._blocks for v, n in zip(b.variables, b.names) if not v.settable_in_step]
        return VariableError(
            f"{self._model.info.model_name}: {fixed} cannot be set between steps: only inputs and tunable "
            f"parameters can; pass parameters and start values to reset() instead"
        )

    def _fail(self, what: str, block: _Block, status: int) -> None:
        names = block.names
        raise FmuError(
            f"{self._model.info.model_name}: {what} of {names} returned {STATUS_NAMES[status]} "
            f"{self._where()}",
            log=self._model.backend.log.recent(),
        )


def _bad_enum(value: float, position: int, block: _Block) -> bool:
    return any(i == position and value not in allowed for i, allowed in block.enums)


def _show(value: Any) -> str:
    if isinstance(value, float | np.floating):
        whole = math.isfinite(value) and value == int(value)
        return str(int(value)) if whole else f"{value:g}"
    return str(value)


def _declared(position: int, block: _Block) -> str:
    var = block.variables[position]
    if var.enum_items:
        return f" (items: {dict(var.enum_items)})"
    if block.kind == _INT:
        low, high = block.ranges[position]
        return f" ({var.type}, range [{low}, {high}])"
    return ""


def _valid_one(value: Any, position: int, block: _Block) -> bool:
    if block.exact:
        low, high = block.ranges[position]
        return isinstance(value, int) and low <= value <= high
    return (
        _valid(np.array([value], dtype=np.float64), block)
        if block.kind != _INT
        else _int_ok(value, block.ranges[position])
    )


def _int_ok(value: Any, bounds: tuple[int, int]) -> bool:
    number = float(value)
    return math.isfinite(number) and number == round(number) and bounds[0] <= number <= bounds[1]


def _exact_part(values: Any, block: _Block) -> list[Any]:
    """The block's values as Python ints where they are whole numbers (else as given, to be refused)."""
    seq = values.tolist() if isinstance(values, np.ndarray) else list(values)
    part: list[Any] = []
    for i in block.index.tolist():
        value = seq[i]
        whole_float = isinstance(value, float | np.floating) and math.isfinite(value) and value == int(value)
        if whole_float or isinstance(value, int | np.integer):
            value = int(value)
        part.append(value)
    return part


def _valid(part: Any, block: _Block) -> bool:
    if block.exact:
        return all(_valid_one(v, i, block) for i, v in enumerate(part)) and _enums_ok(part, block)
    if not np.isfinite(part).all():
        return False
    if block.kind == _FLOAT:
        return True
    if block.kind == _BOOL:
        return bool(np.isin(part, (0.0, 1.0)).all())
    if not (part == np.round(part)).all():
        return False
    info = np.iinfo(block.buf.dtype)
    if not ((part >= info.min) & (part <= info.max)).all():
        return False
    return _enums_ok(part, block)


def _enums_ok(part: Any, block: _Block) -> bool:
    if block.enums and len(part) == len(block.variables):
        return all(part[i] in allowed for i, allowed in block.enums)
    return True
