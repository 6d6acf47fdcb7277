"""Zenoh sessions from command-line style options (peer/client/router, endpoints, config files).

Nodes on one machine find each other by explicit endpoints or scouting; nodes on other machines
connect to a router or to each other (``--connect tcp/host:7447``), optionally with TLS and
user/password authentication as Zenoh configures them (see docs/zenoh.md).
"""

from __future__ import annotations

import contextlib
import json
import logging
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
    """

    config_file: Path | None = None
    mode: str | None = None
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    scouting: bool | None = None

    def to_config(self) -> Any:
        import zenoh

        try:
            config = zenoh.Config.from_file(str(self.config_file)) if self.config_file else zenoh.Config()
        except Exception as exc:
            raise TransportError(f"cannot read the Zenoh configuration {self.config_file}: {exc}") from exc
        try:
            if self.mode:
                config.insert_json5("mode", json.dumps(self.mode))
            if self.listen:
                config.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
            if self.connect:
                config.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
            scouting = self.scouting if self.scouting is not None else not (self.listen or self.connect)
            if not scouting:
                config.insert_json5("scouting/multicast/enabled", "false")
        except Exception as exc:
            raise TransportError(f"invalid Zenoh option: {exc}") from exc
        return config

    def describe(self) -> str:
        parts = [f"mode={self.mode or 'peer'}"]
        if self.listen:
            parts.append(f"listen={list(self.listen)}")
        if self.connect:
            parts.append(f"connect={list(self.connect)}")
        if self.config_file:
            parts.append(f"config={self.config_file}")
        return ", ".join(parts)


ZENOH_MODES = ("peer", "client")


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
