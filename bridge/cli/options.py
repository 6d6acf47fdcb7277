"""What several command modules share: the consoles and the Zenoh and prefix options.

``main`` (the app) and its command modules (``recording``, ``system``) import these from here, so
no command module imports ``main`` back.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

if TYPE_CHECKING:
    from bridge.net.node import FmuNode

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

IsolateOpt = Annotated[
    bool,
    typer.Option(
        "--isolate/--no-isolate",
        help="Run the FMU in a child process: a hung or crashing FMU is killed at the step "
        "deadline and restarted by the next reset (one pipe round trip more per step).",
    ),
]
StepTimeoutOpt = Annotated[
    float,
    typer.Option(
        "--step-timeout", help="Seconds a reset or step may take before the node reports its FMU hung."
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


def close_nodes(nodes: Sequence[FmuNode]) -> None:
    """Close served nodes (``node``, ``system serve``); when a call into an FMU never returned,
    say which node and leave the process at once with exit code 3 (a native call cannot be
    interrupted, and waiting for it would keep the process, and a core, forever)."""
    import os
    import sys

    stuck = [n for n in nodes if not n.close()]
    for n in stuck:
        err_console.print(
            f"node {n.name!r}: {n.health_detail or 'a call into the FMU did not return'}; exiting without it",
            highlight=False,
        )
    if stuck:
        sys.stderr.flush()
        os._exit(3)
