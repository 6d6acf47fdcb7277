"""Real ROS 2 (Jazzy's rclpy with Fast DDS, from PyPI) in the tests.

Every test here runs in a random ROS domain with discovery kept on this machine, and looks at
fmu-bridge from ``probe.py``: a separate plain-rclpy process that imports nothing of the project.
Where rclpy is missing the tests skip with the install line; with ``FMU_BRIDGE_REQUIRE_ROS=1``
(.ci/ros) they fail instead.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.net.ros2.rclpy_backend import INSTALL_HINT

PROBE = Path(__file__).parent / "probe.py"
INSTALL = INSTALL_HINT  # pip install 'fmu-bridge[ros]' ...


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    here = Path(__file__).parent
    # skipped before any fixture (a session-scoped trained agent would be set up first otherwise)
    missing = not rclpy_installed() and os.environ.get("FMU_BRIDGE_REQUIRE_ROS") != "1"
    for item in items:
        if here in Path(str(item.fspath)).parents:
            item.add_marker(pytest.mark.ros)
            item.add_marker(pytest.mark.integration)
            if missing:
                item.add_marker(
                    pytest.mark.skip(reason=f"ROS 2 (rclpy) is not installed; install it with: {INSTALL}")
                )


def rclpy_installed() -> bool:
    return all(importlib.util.find_spec(m) is not None for m in ("rclpy", "sensor_msgs", "std_srvs"))


@pytest.fixture(autouse=True)
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """A random ROS_DOMAIN_ID for this test and every process it starts; discovery on localhost."""
    if not rclpy_installed():
        message = f"ROS 2 (rclpy) is not installed; install it with: {INSTALL}"
        if os.environ.get("FMU_BRIDGE_REQUIRE_ROS") == "1":
            pytest.fail(message)
        pytest.skip(message)
    domain = random.SystemRandom().randint(1, 100)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    monkeypatch.setenv("PYTHONUNBUFFERED", "1")
    return domain


class Probe:
    """The plain-rclpy process: ``ask(op, **fields)`` sends a command and returns its answer."""

    def __init__(self, env: dict[str, str]) -> None:
        import tempfile

        self.log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115  # closed in close()
        self.process = subprocess.Popen(
            [sys.executable, str(PROBE)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,  # a file: a pipe nobody reads would block the probe once full
            text=True,
            env=env,
        )
        first = self._line(60.0)
        assert first == {"ready": True}, first

    def _line(self, timeout_s: float) -> Any:
        assert self.process.stdout is not None
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(self.process.stdout.readline()))  # type: ignore[union-attr]
        reader.daemon = True
        reader.start()
        reader.join(timeout_s)
        if not result or not result[0]:
            self.process.kill()
            self.process.wait(timeout=5)
            self.log.seek(0)
            pytest.fail(f"the rclpy probe did not answer within {timeout_s} s:\n{self.log.read()[-3000:]}")
        return json.loads(result[0])

    def ask(self, op: str, timeout_s: float = 60.0, **fields: Any) -> Any:
        assert self.process.stdin is not None
        self.process.stdin.write(json.dumps({"op": op, **fields}) + "\n")
        self.process.stdin.flush()
        # an op that waits ``timeout`` itself answers after it: wait longer than the op does
        answer = self._line(max(timeout_s, float(fields.get("timeout", 0.0)) + 30.0))
        if "error" in answer:
            pytest.fail(f"probe {op}: {answer['error']}")
        return answer["ok"]

    def wait(self, probe: Any, timeout_s: float = 20.0, what: str = "condition") -> Any:
        """Ask until ``probe()`` returns something true."""
        deadline = time.monotonic() + timeout_s
        value = None
        while time.monotonic() < deadline:
            value = probe()
            if value:
                return value
            time.sleep(0.1)
        pytest.fail(f"{what} not met within {timeout_s} s (last: {value!r})")

    def close(self) -> None:
        if self.process.poll() is None:
            assert self.process.stdin is not None
            with contextlib.suppress(OSError):
                self.process.stdin.write('{"op": "quit"}\n')
                self.process.stdin.flush()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()
        self.log.close()


@pytest.fixture(scope="session")
def exported_run(balancer: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the balancer's run with its policy exported to ONNX and as a policy FMU."""
    import shutil

    from agents.export.onnx import export_onnx
    from agents.export.policy_fmu import export_fmu

    run = tmp_path_factory.mktemp("exported") / "ppo"
    shutil.copytree(balancer, run)
    export_onnx(run)
    export_fmu(run, "2")
    assert (run / "policy.onnx").is_file() and (run / "policy-fmi2.fmu").is_file()
    return run


def predicted_forces(run: Path, states: Any) -> list[float]:
    """The in-process policy's force for each cart-pole state (x, x_dot, theta, theta_dot): PPO.predict."""
    import numpy as np
    from stable_baselines3 import PPO

    best = run / "best_model.zip"
    model = PPO.load(best if best.is_file() else run / "model.zip", device="cpu")
    actions, _ = model.predict(np.asarray(states, dtype=np.float32), deterministic=True)
    return [10.0 if int(a) == 1 else -10.0 for a in actions]  # the experiment's levels [-10, 10]


@pytest.fixture
def probe(ros_domain: int) -> Iterator[Probe]:
    p = Probe(dict(os.environ))
    try:
        yield p
    finally:
        p.close()


class Command:
    """A ``fmu-bridge`` subprocess whose output is read on a thread (never blocks on a full pipe)."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        self.args = args
        self.process = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env or dict(os.environ),
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line)

    @property
    def name(self) -> str:
        return "fmu-bridge " + " ".join(self.args)

    @property
    def output(self) -> str:
        return "".join(self.lines)

    def wait_for(self, text: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if text in " ".join(self.output.split()):  # rich wraps long lines
                return
            if self.process.poll() is not None:
                self._reader.join(5)
                pytest.fail(f"`{self.name}` exited {self.process.returncode}:\n{self.output}")
            time.sleep(0.05)
        pytest.fail(f"`{self.name}` did not print {text!r} in {timeout_s} s:\n{self.output}")

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> float:
        """Send ``sig``; the seconds until the process exited (it is killed after ``timeout_s``)."""
        if self.process.poll() is not None:
            return 0.0
        start = time.monotonic()
        self.process.send_signal(sig)
        try:
            self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(timeout=5)
        elapsed = time.monotonic() - start
        self._reader.join(5)
        return elapsed

    def close(self) -> None:
        self.stop(signal.SIGKILL if self.process.poll() is None else signal.SIGTERM)
        if self.process.stdout is not None:
            self.process.stdout.close()


@contextlib.contextmanager
def command(*args: str, ready: str = "serving", timeout_s: float = 300.0) -> Iterator[Command]:
    """Start ``fmu-bridge ARGS``, wait for ``ready`` in its output, kill it at the end.

    The wait ends as soon as ``ready`` is printed; its deadline is a loaded machine's: a torch agent
    took 80-96 s to be ready beside four CPU burners at a load of 13-16 (benchmarks/
    bench_launch_start.py), importing torch most of it."""
    cmd = Command(list(args))
    try:
        if ready:
            cmd.wait_for(ready, timeout_s)
        yield cmd
    finally:
        cmd.close()


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cart-pole PPO run trained for a few hundred steps: it acts (forces of -10 or +10) without
    balancing anything; for tests of how a deployed agent behaves, not of how well it acts."""
    from agents.train import train
    from bridge.experiment.examples import example_experiment

    run = tmp_path_factory.mktemp("tiny") / "ppo"
    overrides: dict[str, Any] = {"timesteps": 256, "n_envs": 1, "eval_every": 1_000_000}
    overrides["hyperparams"] = {"n_steps": 128, "batch_size": 64, "n_epochs": 1}
    train(example_experiment("cartpole_balance"), overrides=overrides, run_dir=run, progress=False)
    return run
