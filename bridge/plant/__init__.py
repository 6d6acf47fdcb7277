"""Plants: the physics side of an experiment behind one small interface.

A plant serves a model: it says what it serves (``info``), is reset with parameter and start
values, applies input values, advances one sample and returns output values. The env, the task,
recording and evaluation never learn which plant they drive. ``vocab`` is the model vocabulary
(variables, model info, their JSON form) and imports nothing heavy; ``base`` is the interface
and its one error semantics; ``local`` runs an FMU in this process.

May import the experiment and ``bridge.fmu`` (in ``local`` only); never the task, the env, the
network or recording.
"""
