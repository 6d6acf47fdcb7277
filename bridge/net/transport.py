"""Zenoh sessions from command-line style options (peer/client/router, endpoints, config files).

One resolution for the command line and the Python API (:class:`ZenohOptions`, which both
build): loopback unless a network is asked for. A session opened without endpoints, a
configuration file or ``network`` listens on 127.0.0.1 only (an ephemeral port), does not scout
or answer scouting, and connects to the local router (``fmu-bridge router``, which listens on
127.0.0.1:7447 by default; ``FMU_BRIDGE_LOCAL_ROUTER`` names another endpoint). A session that
only connects (``connect``, no ``listen``) is a client of what it connects to
(:func:`session_mode`) and listens nowhere; one in peer or router mode without ``listen``
listens on 127.0.0.1 only. Serving on the network is asked for explicitly: ``network`` (the
``--network`` option: Zenoh's own defaults, every interface and multicast scouting), endpoints
(``--listen``/``--connect``) or a configuration file, such as the TLS and user/password set-ups of
docs/zenoh.md.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bridge.errors import TransportError

_log = logging.getLogger(__name__)
_LOG_ONCE = threading.Lock()
_log_state = {"initialised": False}


@dataclass(frozen=True)
class ZenohOptions:
    """How to open a Zenoh session.

    Args:
        config_file: a Zenoh JSON5 configuration file (applied first; the other options override it).
        mode: ``peer`` (Zenoh's default), ``client`` (through a router) or ``router``; the command
            line chooses it with :func:`session_mode`.
        listen: endpoints to listen on, e.g. ``tcp/127.0.0.1:7447``.
        connect: endpoints to connect to.
        scouting: multicast scouting; off whenever endpoints are given explicitly.
        network: serve on the network with Zenoh's defaults; without it (and without endpoints or
            a configuration file) the session stays on 127.0.0.1 (see the module docstring).
    """

    config_file: Path | None = None
    mode: str | None = None
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    scouting: bool | None = None
    network: bool = False

    @property
    def resolved_mode(self) -> str | None:
        """The session's mode: ``mode`` when given, else as :func:`session_mode` resolves it for
        the command line (client when the session only connects); None: the configuration
        file's, or Zenoh's default (peer)."""
        if self.mode is not None:
            return self.mode
        return session_mode(None, self.listen, self.connect, self.config_file)

    @property
    def loopback_only(self) -> bool:
        """No endpoints, file or ``network`` given: the session stays on 127.0.0.1."""
        return not (self.network or self.listen or self.connect or self.config_file)

    def to_config(self) -> Any:
        import zenoh

        try:
            config = zenoh.Config.from_file(str(self.config_file)) if self.config_file else zenoh.Config()
        except Exception as exc:
            raise TransportError(f"cannot read the Zenoh configuration {self.config_file}: {exc}") from exc
        try:
            mode = self.resolved_mode
            if mode:
                config.insert_json5("mode", json.dumps(mode))
            if not (self.network or self.listen or self.config_file) and mode != "client":
                config.insert_json5("listen/endpoints", json.dumps([LOOPBACK_LISTEN]))
            if self.loopback_only:
                config.insert_json5("connect/endpoints", json.dumps([local_router()]))
            if self.listen:
                config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            if self.connect:
                config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
            scouting = (
                self.scouting
                if self.scouting is not None
                else self.network and not (self.listen or self.connect)
            )
            if not scouting:
                config.insert_json5("scouting/multicast/enabled", "false")
        except Exception as exc:
            raise TransportError(f"invalid Zenoh option: {exc}") from exc
        return config

    def describe(self) -> str:
        parts = [f"mode={self.resolved_mode or 'peer'}"]
        if self.loopback_only:
            parts.append(f"loopback only, via the local router {local_router()}")
        if self.listen:
            parts.append(f"listen={list(self.listen)}")
        if self.connect:
            parts.append(f"connect={list(self.connect)}")
        if self.config_file:
            parts.append(f"config={self.config_file}")
        return ", ".join(parts)


ZENOH_MODES = ("peer", "client")
LOOPBACK_LISTEN = "tcp/127.0.0.1:0"
LOCAL_ROUTER = "tcp/127.0.0.1:7447"
LOCAL_ROUTER_ENV = "FMU_BRIDGE_LOCAL_ROUTER"


def local_router() -> str:
    """The endpoint of the local router that sessions without options connect to."""
    return os.environ.get(LOCAL_ROUTER_ENV) or LOCAL_ROUTER


def router_endpoints(network: bool) -> list[str]:
    """Where ``fmu-bridge router`` listens without ``--listen``: the local router endpoint, or
    every interface on port 7447 with ``network``."""
    return ["tcp/0.0.0.0:7447"] if network else [local_router()]


def session_mode(
    mode: str | None, listen: tuple[str, ...], connect: tuple[str, ...], config: Path | None
) -> str | None:
    """The Zenoh mode of a command-line session: ``--zenoh-mode`` (client or peer) when given;
    else client when the session only connects (``--connect``, no ``--listen``): to a router, as
    rmw_zenoh lays out a ROS 2 system, and the mode that works from behind NAT, a firewall or a
    container, since nothing has to connect back; else peer. ``None`` leaves the mode to Zenoh's
    default (peer) or to ``--zenoh-config``, whose own mode wins when the option is not given."""
    if mode is not None:
        if mode not in ZENOH_MODES:
            raise TransportError(f"--zenoh-mode {mode!r} is unknown; use client or peer")
        if mode == "client" and listen:
            raise TransportError(
                f"--zenoh-mode client with --listen {list(listen)}: a client does not accept "
                "connections; drop --listen, or use --zenoh-mode peer"
            )
        return mode
    if config is not None:
        return None
    return "client" if connect and not listen else None


def quiet_zenoh_logs(level: str = "error") -> None:
    """Zenoh logs through its own logger; keep it to errors unless RUST_LOG says otherwise."""
    with _LOG_ONCE:
        if _log_state["initialised"]:
            return
        import zenoh

        try:
            zenoh.init_log_from_env_or(level)
        except Exception:  # already initialised by the host application
            _log.debug("zenoh logging was already initialised")
        _log_state["initialised"] = True


def undeclare(entity: Any, attempts: int = 100) -> None:
    """Undeclare a Zenoh entity; while one of its callbacks is running, zenoh-python answers
    "Already borrowed": wait for the callback to finish and try again."""
    for _ in range(attempts):
        try:
            entity.undeclare()
            return
        except RuntimeError as exc:
            if "borrowed" not in str(exc):
                raise
            time.sleep(0.01)
    _log.warning("could not undeclare %r: a callback kept it busy", entity)


def wait_connected(session: Any, timeout_s: float = 2.0, settle_s: float = 0.2) -> bool:
    """Wait until the session has a router or peer, then ``settle_s`` for declarations to arrive."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        info = session.info
        if list(info.routers_zid()) or list(info.peers_zid()):
            time.sleep(settle_s)
            return True
        time.sleep(0.02)
    return False


def open_session(options: ZenohOptions | None = None) -> Any:
    """Open a Zenoh session; a bad endpoint or config is a TransportError naming it."""
    import zenoh

    options = options or ZenohOptions()
    quiet_zenoh_logs()
    config = options.to_config()
    try:
        session = zenoh.open(config)
    except Exception as exc:
        raise TransportError(
            f"cannot open a Zenoh session ({options.describe()}): {exc}; check that the endpoints are "
            "free (listen) or reachable (connect)"
        ) from exc
    _close_at_exit(session)
    return session


def _close_at_exit(session: Any) -> None:
    """Zenoh's callback threads are not daemons: a session left open would hang interpreter exit.

    ``threading._register_atexit`` runs before non-daemon threads are joined (``atexit`` runs too
    late for that), so an unclosed session is closed there; closing twice is harmless.
    """
    register = getattr(threading, "_register_atexit", None)
    if register is None:
        return

    def close() -> None:
        if not session.is_closed():
            session.close()

    with contextlib.suppress(RuntimeError):  # the interpreter is already shutting down
        register(close)
