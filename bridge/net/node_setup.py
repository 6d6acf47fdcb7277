"""What an ``FmuNode`` is built from: its arguments checked, its plant and what it serves.

Everything here runs before the node declares anything on Zenoh, so a bad argument or a model
the node cannot serve fails with a clear error and leaves nothing open.
"""

from __future__ import annotations

from bridge.errors import BridgeError
from bridge.experiment.safe import check_safe_name
from bridge.net.served import Served
from bridge.plant.base import Plant
from bridge.plant.factory import fmu_plant
from bridge.plant.spec import PlantSpec


def check_step_timeout(step_timeout_s: float) -> None:
    """A BridgeError unless the step deadline is a positive number of seconds."""
    if not step_timeout_s > 0:
        raise BridgeError(f"--step-timeout must be > 0 seconds, got {step_timeout_s}")


def check_arguments(name: str, mode: str, rate: float, step_timeout_s: float) -> None:
    """A BridgeError saying what is wrong with the node's arguments, before anything starts."""
    if mode not in ("lockstep", "realtime"):
        raise BridgeError(f"node mode {mode!r} is unknown; use lockstep or realtime")
    if rate < 0:
        raise BridgeError(f"--rate must be >= 0 (0: as fast as possible), got {rate}")
    check_step_timeout(step_timeout_s)
    try:  # a part of every key (<prefix>/<name>/...): no '/', wildcard or '$' may widen it
        check_safe_name(name)
    except ValueError as exc:
        raise BridgeError(f"the node name: {exc}; give --name or node.name a plain one") from None


def served_plant(
    spec: PlantSpec, served: Served, *, isolate: bool, step_timeout_s: float
) -> tuple[Plant, float]:
    """The plant ``spec`` describes, from the factory envs use, bound to what it serves, and the
    longest a reset or step may take on it."""
    plant = fmu_plant(spec, isolate=isolate, timeout_s=step_timeout_s)
    # isolated (by --isolate or the description's isolation alike): the plant's own deadline
    # bounds every call (model.isolation.timeout, else step_timeout_s) and kills the child at it
    if plant.isolated:
        step_timeout_s = float(getattr(plant, "timeout_s", step_timeout_s))
    try:
        plant.bind(served.input_names, served.output_names)
    except BaseException:
        plant.close()
        raise
    return plant, step_timeout_s
