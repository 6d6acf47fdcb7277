"""Zenoh set-ups from launch_scripts/zenoh/: user/password and TLS, with a node as a real subprocess."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import free_port

from bridge.env import RemoteFmuEnv
from bridge.errors import TransportError
from bridge.experiment.examples import example_experiment
from bridge.net.transport import ZenohOptions, open_session

pytestmark = pytest.mark.integration
CONFIGS = Path(__file__).resolve().parents[2] / "launch_scripts" / "zenoh"


def render(name: str, target: Path, **replace: str) -> Path:
    text = (CONFIGS / name).read_text()
    for key, value in replace.items():
        text = text.replace(key, value)
    out = target / name
    out.write_text(text)
    return out


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.glob("*.json5")))
def test_shipped_configs_parse(name: str) -> None:
    ZenohOptions(config_file=CONFIGS / name).to_config()


@contextlib.contextmanager
def node(
    experiment: Path, name: str, prefix: str, config: Path, cwd: Path
) -> Iterator[subprocess.Popen[str]]:
    cmd = [
        sys.executable,
        "-m",
        "bridge.cli",
        "node",
        str(experiment),
        "--name",
        name,
        "--prefix",
        prefix,
        "--zenoh-config",
        str(config),
    ]
    process = subprocess.Popen(
        cmd,
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        assert process.stdout is not None
        line = process.stdout.readline()
        assert "serving" in line, line + process.stdout.read()
        yield process
    finally:
        process.terminate()
        process.wait(timeout=10)


def step_a_few(session: object, prefix: str) -> None:
    experiment = example_experiment("cartpole_balance")
    env = RemoteFmuEnv(experiment, "secure", session=session, prefix=prefix)
    try:
        env.reset(seed=0)
        for _ in range(5):
            obs, *_ = env.step(1)
        assert np.isfinite(obs).all()
    finally:
        env.close()


def test_user_password_authentication(tmp_path: Path) -> None:
    port = str(free_port())
    (tmp_path / "credentials.txt").write_text("worker:s3cret\n")
    router_cfg = render(
        "router_usrpwd.json5", tmp_path, **{"0.0.0.0:7447": f"127.0.0.1:{port}", "CHANGE_ME": "routerpw"}
    )
    client_cfg = render(
        "client_usrpwd.json5", tmp_path, ROUTER_HOST="127.0.0.1", CHANGE_ME="s3cret", **{":7447": f":{port}"}
    )
    prefix = f"auth_{uuid.uuid4().hex[:8]}"
    cwd = os.getcwd()
    os.chdir(tmp_path)  # the dictionary file is relative to the working directory
    try:
        router = open_session(ZenohOptions(config_file=router_cfg))
    finally:
        os.chdir(cwd)
    try:
        with node(example_experiment("cartpole_balance"), "secure", prefix, client_cfg, tmp_path):
            step_a_few(router, prefix)
        (tmp_path / "wrong").mkdir()
        wrong = render(
            "client_usrpwd.json5",
            tmp_path / "wrong",
            ROUTER_HOST="127.0.0.1",
            CHANGE_ME="wrong",
            **{":7447": f":{port}"},
        )
        text = wrong.read_text()
        wrong.write_text(
            re.sub(
                r"connect: \{ endpoints: (\[[^]]*\]) \}",
                r"connect: { endpoints: \1, timeout_ms: 1500 }",
                text,
            )
        )
        with pytest.raises(TransportError, match="cannot open a Zenoh session"):
            open_session(ZenohOptions(config_file=wrong))
    finally:
        router.close()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make test certificates")
def test_tls_router_and_node(tmp_path: Path) -> None:
    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp_path, check=True, capture_output=True, timeout=60)

    ssl(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "ca.key",
        "-out",
        "ca.pem",
        "-days",
        "2",
        "-subj",
        "/CN=test CA",
        "-addext",
        "basicConstraints=critical,CA:TRUE",
        "-addext",
        "keyUsage=critical,keyCertSign,cRLSign",
    )
    ssl(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-keyout",
        "server.key",
        "-out",
        "server.csr",
        "-subj",
        "/CN=localhost",
    )
    (tmp_path / "ext.cnf").write_text("subjectAltName=DNS:localhost\nextendedKeyUsage=serverAuth\n")
    ssl(
        "x509",
        "-req",
        "-in",
        "server.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-out",
        "server.pem",
        "-days",
        "2",
        "-extfile",
        "ext.cnf",
    )
    port = str(free_port())
    router_cfg = render(
        "router_tls.json5",
        tmp_path,
        **{
            "0.0.0.0:7447": f"127.0.0.1:{port}",
            '"server.key"': f'"{tmp_path / "server.key"}"',
            '"server.pem"': f'"{tmp_path / "server.pem"}"',
        },
    )
    client_cfg = render(
        "client_tls.json5",
        tmp_path,
        ROUTER_HOST="localhost",
        **{":7447": f":{port}", '"ca.pem"': f'"{tmp_path / "ca.pem"}"'},
    )
    prefix = f"tls_{uuid.uuid4().hex[:8]}"
    router = open_session(ZenohOptions(config_file=router_cfg))
    try:
        with node(example_experiment("cartpole_balance"), "secure", prefix, client_cfg, tmp_path):
            step_a_few(router, prefix)
    finally:
        router.close()
