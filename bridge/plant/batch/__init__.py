"""Batched stepping: N instances of one FMU per process, stepped in one native call.

``plant`` holds ``BatchPlant`` (episodes, per-instance reset and status, from a ``PlantSpec``) over a
``bridge.fmu.ModelBatch``, which makes every FMU call (one native call for the batch where it
can, else the same FMI calls from Python). Imports like ``bridge.plant``: the experiment,
``bridge.fmu`` and the example-model cache (``bridge.models``); never the task or the env.
"""

from bridge.plant.batch.plant import BatchPlant, BatchStep

__all__ = ["BatchPlant", "BatchStep"]
