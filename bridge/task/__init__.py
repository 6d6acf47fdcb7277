"""The task: what an experiment adds on top of a model, wherever the model runs.

Action mapping, observations (selection, scaling, history, noise), rewards, termination and
scenarios. Runs the same way over every plant and inside a deployed agent. May import the
experiment and the model vocabulary (``bridge.fmu.vocab``); never the FMU runtime, the env,
the network or recording.
"""

from bridge.task.core import SignalNames, Task, load_callable, task_signal_names

__all__ = ["SignalNames", "Task", "load_callable", "task_signal_names"]
