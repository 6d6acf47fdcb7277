"""``RemoteFmuEnv``: the one env over a node's model (a ``RemotePlant`` over Zenoh)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError
from bridge.experiment.config import Experiment, as_experiment
from bridge.experiment.validate import resolve_state_file, timing
from bridge.net import protocol as proto
from bridge.net.remote import RemotePlant
from bridge.net.transport import ZenohOptions


class RemoteFmuEnv(FmuEnv):
    """``FmuEnv`` with the model in a node (lockstep over Zenoh).

    Args:
        experiment: the experiment (the same file the node was started with).
        node: the node's name.
        options: how to open a Zenoh session (ignored when ``session`` is given).
        timeout_s: how long a step or reset may take before :class:`StepTimeout`.
        take_over: take the node over from the client that holds it.
    """

    def __init__(
        self,
        experiment: Experiment | str | Path,
        node: str,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = proto.DEFAULT_PREFIX,
        timeout_s: float = 5.0,
        version: str | None = None,
        render_mode: str | None = None,
        take_over: bool = False,
    ) -> None:
        exp = as_experiment(experiment, version)
        own = resolve_state_file(exp)  # the node gets the file from here: its machine need not have it
        plant = RemotePlant(
            node,
            options=options,
            session=session,
            prefix=prefix,
            timeout_s=timeout_s,
            take_over=take_over,
            state=_read_state(own) if own is not None else None,
            where=f" [{exp.source}]" if exp.source else "",
        )
        try:  # the node must step as this experiment does (its checks: the env's, over the node's model)
            expected = timing(exp, plant.info)
            plant.check_timing(expected.sampling_time_s, expected.start_time_s)
        except BaseException:
            plant.close()
            raise
        super().__init__(exp, render_mode=render_mode, plant=plant)
        self.node = node
        self._remote = plant
        try:
            self._check_same_names()
        except BaseException:
            self.close()
            raise

    def _check_same_names(self) -> None:
        """The node must serve exactly what this env's task drives and reads, in order: a node
        started from another experiment file is refused here, before the first reset."""
        d = self._remote.client.description
        mine = {"inputs": list(self.task.input_names), "outputs": list(self.task.output_names)}
        theirs = {"inputs": list(d["input_names"]), "outputs": list(d["output_names"])}
        mismatches = [f"{k} {mine[k]} vs the node's {theirs[k]}" for k in mine if mine[k] != theirs[k]]
        if mismatches:
            raise ConfigError(
                f"node {self.node!r} serves experiment {d.get('experiment')!r} with "
                f"{'; '.join(mismatches)}; start the node with the same experiment file "
                f"({self.experiment.source})"
            )

    def start_from(self, state: str | Path | bytes) -> dict[str, Any]:
        """Hand the node a state file (a path here, or its bytes): from the next reset on, its
        episodes start from that state (``bridge.net.node_start``); the node's answer."""
        data = state if isinstance(state, bytes) else _read_state(Path(state))
        return self._remote.start_from(data)

    def clear_start(self) -> dict[str, Any]:
        """Drop the state sent to the node: from the next reset on, its episodes start as the
        node's own experiment says (its state file, else initialisation)."""
        return self._remote.clear_start()


def _read_state(path: Path) -> bytes:
    """A state file's bytes, checked here first (sizes, checksum)."""
    from bridge.fmu import state_file

    saved = state_file.read(path)
    return state_file.encode(saved.header, saved.payload)
