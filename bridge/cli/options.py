"""What several command modules share: the consoles and the Zenoh and prefix options.

``main`` (the app) and its command modules (``recording``, ``system``) import these from here, so
no command module imports ``main`` back.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

console = Console()
err_console = Console(stderr=True)

ZenohConfigOpt = Annotated[Path | None, typer.Option("--zenoh-config", help="A Zenoh JSON5 config file.")]
ListenOpt = Annotated[
    list[str] | None, typer.Option("--listen", help="Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447.")
]
ConnectOpt = Annotated[list[str] | None, typer.Option("--connect", help="Zenoh endpoint to connect to.")]
ZenohModeOpt = Annotated[
    str | None,
    typer.Option(
        "--zenoh-mode",
        help="client (all traffic through the router) or peer; default: client when only "
        "--connect is given (a router), else peer.",
    ),
]
PrefixOpt = Annotated[str, typer.Option("--prefix", help="Key expression prefix of the nodes.")]
NetworkOpt = Annotated[
    bool,
    typer.Option(
        "--network",
        help="Serve on the network: every interface and multicast scouting (Zenoh's defaults). "
        "Without it, and without --listen/--connect/--zenoh-config, only 127.0.0.1 through the "
        "local router (see docs/zenoh.md).",
    ),
]


def zenoh_options(
    config: Path | None,
    listen: list[str] | None,
    connect: list[str] | None,
    mode: str | None = None,
    zenoh_mode: str | None = None,
    *,
    network: bool = False,
) -> Any:
    from bridge.net.transport import ZenohOptions, session_mode

    listen_t, connect_t = tuple(listen or ()), tuple(connect or ())
    chosen = mode or session_mode(zenoh_mode, listen_t, connect_t, config)
    return ZenohOptions(config_file=config, mode=chosen, listen=listen_t, connect=connect_t, network=network)
