"""Safe by default: a node and a router started without network options stay on 127.0.0.1.

A node with no options once listened on every interface and answered multicast scouting, and
``fmu-bridge router`` listened on 0.0.0.0: a stranger on the LAN found and drove them. Now both
listen on loopback only and open no scouting socket; they still find each other through the local
router, and ``--network`` (or endpoints, or a Zenoh configuration file) serves on the network.
"""

from __future__ import annotations

import ipaddress
import json
import os
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import psutil
import pytest

from bridge.experiment.examples import example_experiment
from bridge.net.transport import LOCAL_ROUTER_ENV, ZenohOptions, router_endpoints
from tests.conftest import _wait_for_line, free_port, stop_process

SCOUTING_PORT = 7446


@contextmanager
def cli(*args: str, env: dict[str, str], ready: str) -> Iterator[subprocess.Popen[str]]:
    process = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **env},
    )
    try:
        _wait_for_line(process, ready, timeout_s=60)
        yield process
    finally:
        stop_process(process, timeout_s=10)


def sockets(pid: int) -> tuple[list[tuple[str, int]], list[tuple[str, int]]]:
    """(TCP listening addresses, UDP bound addresses) of the process ``pid``."""
    connections = psutil.Process(pid).net_connections(kind="inet")
    listening = [(c.laddr.ip, c.laddr.port) for c in connections if c.status == psutil.CONN_LISTEN]
    udp = [(c.laddr.ip, c.laddr.port) for c in connections if c.type == 2]  # SOCK_DGRAM
    return listening, udp


def is_loopback(ip: str) -> bool:
    return ipaddress.ip_address(ip).is_loopback


def test_a_node_and_a_router_without_options_listen_on_loopback_only_and_do_not_scout(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {LOCAL_ROUTER_ENV: endpoint}  # the local router's endpoint, on a port of this test's own
    name, prefix = "safe-default", f"test_{uuid.uuid4().hex[:10]}"
    with (
        cli("router", env=env, ready="listening") as router,
        cli(
            "node",
            str(example_experiment("dcmotor_tracking")),
            "--name",
            name,
            "--prefix",
            prefix,
            env=env,
            ready="serving",
        ) as node,
    ):
        for process in (router, node):
            listening, udp = sockets(process.pid)
            assert listening, f"process {process.pid} listens nowhere"
            assert all(is_loopback(ip) for ip, _ in listening), listening
            assert not [a for a in udp if a[1] == SCOUTING_PORT or not is_loopback(a[0])], udp
        assert sockets(router.pid)[0] == [("127.0.0.1", int(endpoint.rsplit(":", 1)[1]))]
        deadline, found = time.monotonic() + 30, []
        while time.monotonic() < deadline and not found:  # and it is reachable through the router
            listed = subprocess.run(
                [sys.executable, "-m", "bridge.cli", "nodes", "--prefix", prefix, "--json"],
                capture_output=True,
                text=True,
                env={**os.environ, **env},
                timeout=60,
                check=False,
            )
            found = [entry["node"] for entry in json.loads(listed.stdout or "[]") if "error" not in entry]
        assert found == [name], listed.stdout + listed.stderr


def test_network_options_are_explicit() -> None:
    quiet = ZenohOptions().to_config()
    assert json.loads(quiet.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(quiet.get_json("scouting/multicast/enabled")) is False
    network = ZenohOptions(network=True).to_config()
    assert json.loads(network.get_json("scouting/multicast/enabled")) is not False
    assert "127.0.0.1" not in network.get_json("listen/endpoints")
    assert router_endpoints(network=False) == ["tcp/127.0.0.1:7447"] or os.environ.get(LOCAL_ROUTER_ENV)
    assert router_endpoints(network=True) == ["tcp/0.0.0.0:7447"]


@pytest.mark.parametrize(
    "options", [ZenohOptions(connect=("tcp/127.0.0.1:1",)), ZenohOptions(listen=("tcp/127.0.0.1:0",))]
)
def test_explicit_endpoints_keep_scouting_off(options: ZenohOptions) -> None:
    assert json.loads(options.to_config().get_json("scouting/multicast/enabled")) is False


@pytest.mark.integration
@pytest.mark.parametrize("mode", [None, "peer"])
def test_the_python_api_connecting_to_a_router_listens_on_no_network_interface(mode: str | None) -> None:
    """``ZenohOptions(connect=[router])``, the form the docs show, once listened on every
    interface while the command line kept the same options on loopback: both resolve alike now
    (a client of the router, or a peer listening on 127.0.0.1 only)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    code = (
        "import sys\n"
        "from bridge.net.transport import ZenohOptions, open_session\n"
        "mode = sys.argv[2] or None\n"
        "session = open_session(ZenohOptions(mode=mode, connect=(sys.argv[1],)))\n"
        "print('ready', flush=True)\n"
        "sys.stdin.read()\n"
        "session.close()\n"
    )
    router = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "router", "--listen", endpoint],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    try:
        _wait_for_line(router, "listening", timeout_s=60)
        process = subprocess.Popen(
            [sys.executable, "-c", code, endpoint, mode or ""],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        try:
            _wait_for_line(process, "ready", timeout_s=60)
            listening, _ = sockets(process.pid)
            assert all(is_loopback(ip) for ip, _ in listening), listening
            assert ZenohOptions(mode=mode, connect=(endpoint,)).resolved_mode == (mode or "client")
        finally:
            stop_process(process, timeout_s=10)
    finally:
        stop_process(router, timeout_s=10)
