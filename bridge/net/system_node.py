"""The client's side of a system's components served by nodes: their plants on one session.

A component with ``node: NAME`` runs in an :class:`bridge.net.node.FmuNode` of that name, started
by ``fmu-bridge system serve SYSTEM.yaml`` (what it serves and runs is composed above the network,
in ``bridge.serving.system``). Both sides read the same system file, so they agree on the names;
the client (:class:`bridge.net.remote.RemotePlant`, built here with the macro step and the
component's own values) maps its bound inputs and outputs onto the node's lists by name and says
so when they do not fit.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bridge.errors import TransportError
from bridge.fmu.vocab import ModelInfo, info_from_summary
from bridge.net import protocol as proto
from bridge.net.channel import ChannelWaiting
from bridge.net.remote import SERVE_HINT, RemotePlant
from bridge.plant.base import Plant
from bridge.plant.system.description import Component

if TYPE_CHECKING:
    from bridge.net.transport import ZenohOptions

__all__ = ["SERVE_HINT", "NodeComponents"]


class NodeComponents:
    """Builds the plants of a system's node components on one shared Zenoh session.

    Given to ``SystemPlant(remote=...)`` by the env, so that plants never import the network.

    Args:
        options: how to open the session (when ``session`` is None; opened on first use).
        session: an open session to share (owned by the caller).
        prefix: the key prefix the component nodes serve under.
        timeout_s: how long a reset or macro step may take before :class:`StepTimeout`.
    """

    def __init__(
        self,
        *,
        options: ZenohOptions | None = None,
        session: Any = None,
        prefix: str = "fmu_bridge",
        timeout_s: float = 10.0,
    ) -> None:
        self._options, self._session, self._own = options, session, False
        self.prefix, self.timeout_s = prefix, timeout_s
        self._infos: dict[str, dict[str, Any]] = {}

    def _open(self) -> Any:
        if self._session is None:
            from bridge.net.transport import open_session

            self._session, self._own = open_session(self._options), True
        return self._session

    def __call__(self, component: Component, step_size_s: float, start_time_s: float, where: str) -> Plant:
        session = self._open()
        try:
            return RemotePlant(  # answers wait in a ring channel: the master waits for every node in turn
                component.node or component.name,
                session=session,
                prefix=self.prefix,
                timeout_s=self.timeout_s,
                waiting=ChannelWaiting(),
                sampling_time_s=step_size_s,
                start_time_s=start_time_s,
                defaults={**component.parameters, **component.start_values},
                label=f"component {component.name!r} (node {component.node or component.name!r})",
                where=where,
            )
        except TransportError as exc:
            raise self._missing(component, exc) from exc

    def describe(self, component: Component) -> ModelInfo:
        """The component's model as its node reports it (the FMU need not be on this machine)."""
        return info_from_summary(self._info(component)["model"])

    def checksum(self, component: Component) -> str:
        """The SHA-256 of the FMU the component's node serves."""
        return str(self._info(component).get("fmu_sha256", ""))

    def _info(self, component: Component) -> dict[str, Any]:
        from bridge.net.remote import query_info

        node = component.node or component.name
        if node not in self._infos:
            session = self._open()
            try:
                self._infos[node] = query_info(session, proto.Keys(self.prefix, node), self.timeout_s)
            except TransportError as exc:
                raise self._missing(component, exc) from exc
        return self._infos[node]

    def _missing(self, component: Component, exc: TransportError) -> TransportError:
        """A component's node not found, said for a system: how to serve it, and the Zenoh mode."""
        if "no FMU node named" not in str(exc):
            return exc
        node, options = component.node or component.name, self._options
        hint = ""
        if options is not None and options.mode == "client" and len(options.connect) > 1:
            hint = (
                f"; this session runs in Zenoh client mode (--connect without --listen), which "
                f"reaches one router, not each of {list(options.connect)}: add --zenoh-mode peer to "
                f"connect to every endpoint"
            )
        elif options is not None and options.mode == "client":
            hint = f"; this session is a Zenoh client of {list(options.connect)}: the node must reach it too"
        return TransportError(
            f"system component {component.name!r}: no node {node!r} answers within {self.timeout_s:g} s "
            f"(prefix {self.prefix!r}); serve it with `fmu-bridge system serve EXPERIMENT --component "
            f"{component.name}` where its FMU is, and check the Zenoh endpoints{hint} "
            f"(`fmu-bridge nodes` lists the live ones)"
        )

    def close(self) -> None:
        if self._own and self._session is not None:
            self._session.close()
        self._session = None
