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

from bridge.env import RemoteFmuEnv
from bridge.errors import TransportError
from bridge.experiment.examples import example_experiment
from bridge.net.transport import ZenohOptions, open_session
from tests.conftest import free_port

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


# -- TLS with user/password, and mutual TLS (certificates made here, 127.0.0.1 only) ------------------
def make_certificates(where: Path) -> None:
    """A CA, a server certificate for localhost, a client certificate and one from a stranger's CA."""

    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=where, check=True, capture_output=True, timeout=60)

    for ca in ("ca", "rogue_ca"):
        ssl(
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{ca}.key", "-out", f"{ca}.pem",
            "-days", "2", "-subj", f"/CN=test {ca}", "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign",
        )  # fmt: skip
    leaves = {
        "server": ("ca", "subjectAltName=DNS:localhost\nextendedKeyUsage=serverAuth\n"),
        "client": ("ca", "extendedKeyUsage=clientAuth\n"),
        "rogue": ("rogue_ca", "extendedKeyUsage=clientAuth\n"),
    }
    for name, (ca, extensions) in leaves.items():
        ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr",
            "-subj", f"/CN={name}")  # fmt: skip
        (where / f"{name}.ext").write_text(extensions)
        ssl("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
            "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.ext")  # fmt: skip


def absolute(config: Path, where: Path, names: tuple[str, ...]) -> None:
    text = config.read_text()
    for name in names:
        text = text.replace(f'"{name}"', f'"{where / name}"')
    config.write_text(text.replace("connect: { endpoints: [", "connect: { timeout_ms: 1500, endpoints: ["))


def client_config(name: str, where: Path, port: str, **replace: str) -> Path:
    (where / "clients").mkdir(exist_ok=True)
    config = render(name, where / "clients", ROUTER_HOST="localhost", **{":7447": f":{port}"}, **replace)
    absolute(config, where, ("ca.pem", "client.key", "client.pem"))
    return config


def router_config(name: str, where: Path, port: str) -> Path:
    config = render(name, where, **{"0.0.0.0:7447": f"127.0.0.1:{port}", "CHANGE_ME": "routerpw"})
    absolute(config, where, ("ca.pem", "server.key", "server.pem"))
    return config


def refused(config: Path) -> None:
    with pytest.raises(TransportError, match="cannot open a Zenoh session"):
        open_session(ZenohOptions(config_file=config)).close()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make test certificates")
def test_tls_with_user_password_admits_only_the_right_password(tmp_path: Path) -> None:
    make_certificates(tmp_path)
    (tmp_path / "credentials.txt").write_text("worker:s3cret\n")
    port = str(free_port())
    router_cfg = router_config("router_tls_usrpwd.json5", tmp_path, port)
    good = client_config("client_tls_usrpwd.json5", tmp_path, port, CHANGE_ME="s3cret")
    cwd = os.getcwd()
    os.chdir(tmp_path)  # the dictionary file is relative to the working directory
    try:
        router = open_session(ZenohOptions(config_file=router_cfg))
    finally:
        os.chdir(cwd)
    try:
        prefix = f"tlspw_{uuid.uuid4().hex[:8]}"
        with node(example_experiment("cartpole_balance"), "secure", prefix, good, tmp_path):
            step_a_few(router, prefix)
        (tmp_path / "wrong").mkdir()
        refused(client_config("client_tls_usrpwd.json5", tmp_path / "wrong", port, CHANGE_ME="guess"))
        # the CA alone (what TLS without a password admits) is not enough
        plain_tls = client_config("client_tls.json5", tmp_path / "wrong", port)
        refused(plain_tls)
    finally:
        router.close()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make test certificates")
def test_mutual_tls_admits_only_clients_with_a_certificate_from_the_ca(tmp_path: Path) -> None:
    make_certificates(tmp_path)
    port = str(free_port())
    router = open_session(ZenohOptions(config_file=router_config("router_mtls.json5", tmp_path, port)))
    try:
        prefix = f"mtls_{uuid.uuid4().hex[:8]}"
        good = client_config("client_mtls.json5", tmp_path, port)
        with node(example_experiment("cartpole_balance"), "secure", prefix, good, tmp_path):
            step_a_few(router, prefix)
        (tmp_path / "others").mkdir()
        refused(client_config("client_tls.json5", tmp_path / "others", port))  # no client certificate
        rogue = client_config("client_mtls.json5", tmp_path / "others", port)
        rogue.write_text(
            rogue.read_text().replace("client.key", "rogue.key").replace("client.pem", "rogue.pem")
        )
        refused(rogue)
    finally:
        router.close()
