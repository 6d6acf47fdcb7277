"""Plants: the physics side of an experiment behind one small interface.

A plant serves a model: it says what it serves (``info``), is reset with parameter and start
values, applies input values, advances one sample and returns output values. The env, the task,
recording and evaluation never learn which plant they drive. ``base`` is the interface and its
one error semantics (with defaults for what only some plants do: saved states, components,
answer readiness); ``local`` runs an FMU in this process (``instance``: what it shares with a
system's in-process components), ``isolated`` in a child process behind a deadline, ``system``
couples several FMUs, ``batch`` runs N instances of one FMU for the batched env. The network's
``bridge.net.remote.RemotePlant`` is a node's model. Every FMU call is made in ``bridge.fmu``.

May import the experiment and ``bridge.fmu``; never the task, the env, the network or recording.
"""
