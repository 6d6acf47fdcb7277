"""Batched stepping: N instances of one FMU per process, stepped in one native call.

``plant`` holds ``BatchPlant`` (the instances, per-instance reset and status), ``native`` builds
and binds the C stepper (``batch.c``) and says when it cannot, in which case the plant steps the
same FMI calls from Python. Imports like ``bridge.plant``: the experiment, ``bridge.fmu`` and the
example-model cache (``bridge.models``); never the task or the env.
"""

from bridge.plant.batch.plant import BatchPlant, BatchStep

__all__ = ["BatchPlant", "BatchStep"]
