"""Plants: the physics side of an experiment behind one small interface.

A plant serves a model: it says what it serves (``info``), is reset with parameter and start
values, applies input values, advances one sample and returns output values. The env, the task,
recording and evaluation never learn which plant they drive. ``base`` is the interface and its
one error semantics; ``local`` runs an FMU in this process, ``isolated`` in a child process
behind a deadline. The network's ``bridge.net.remote.RemotePlant`` is a node's model.

May import the experiment and ``bridge.fmu``; never the task, the env, the network or recording.
"""
