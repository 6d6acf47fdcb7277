"""``fmu-bridge system serve --isolate --step-timeout``: each served component's FMU runs in a child
process with a deadline, as with ``fmu-bridge node --isolate --step-timeout`` (real subprocesses,
a real FMU that hangs or forks, a system client over Zenoh on 127.0.0.1)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from bridge.env.fmu_env import FmuEnv
from bridge.errors import StepTimeout
from bridge.experiment.config import load_experiment
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from tests.conftest import Loopback, wait_until
from tests.net.test_node_health import busy_in_a_forked_step, gone, plain_info, plant_processes
from tests.plant.test_system_nodes import serve

pytestmark = pytest.mark.integration
SYSTEM = """\
model: {step_size: 0.1, episode_duration: 5.0}
system:
  components:
    typed: {fmu: 'example:typed', node: typed-node}
actions: {inputs: [typed.real_in], low: {typed.real_in: -1}, high: {typed.real_in: 1}}
observations: {outputs: [typed.real_out, typed.counter]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {}
  hangs: {parameters: {typed.fault_at_step: 2, typed.fault_kind: 1}}
  forks: {parameters: {typed.fault_at_step: 3, typed.fault_kind: 4}}
schedule: {mode: fixed}
"""
HALF = np.array([0.5], dtype=np.float32)


def own_net(net: Loopback) -> Loopback:
    return Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)


def system_env(file: Path, net: Loopback, timeout_s: float) -> FmuEnv:
    remote = NodeComponents(session=net.session, prefix=net.prefix, timeout_s=timeout_s)
    return FmuEnv(file, plant=SystemPlant(load_experiment(file), remote=remote))


def fine_episode(env: FmuEnv) -> list[list[float]]:
    env.reset(options={"scenario": "fine"})
    return [env.step(HALF)[0].tolist() for _ in range(3)]


def stop(process: subprocess.Popen[str]) -> float:
    """SIGTERM; how long the process took to exit."""
    process.send_signal(signal.SIGTERM)
    started = time.monotonic()
    process.wait(timeout=30)
    return time.monotonic() - started


def test_a_hung_component_in_an_isolated_system_node_is_the_single_nodes_error_and_heals(
    net: Loopback, tmp_path: Path
) -> None:
    file = tmp_path / "typed_system.yaml"
    file.write_text(SYSTEM)
    own = own_net(net)
    with serve(file, own, "typed", extra=("--isolate", "--step-timeout", "5")) as process:
        (child,) = plant_processes(process)
        described = plain_info(own, "typed-node")
        assert described["isolated"] is True and described["step_timeout_s"] == 5.0
        with system_env(file, own, timeout_s=60) as env:
            assert fine_episode(env) == [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]]
            env.reset(options={"scenario": "hangs"})
            env.step(HALF)
            start = time.monotonic()
            with pytest.raises(StepTimeout) as caught:
                env.step(HALF)
            assert time.monotonic() - start < 30  # the node's 5 s deadline, not the client's 60 s
            # the node's answer as a remote env reads it (tests/net/test_node_faults.py), then
            # as the system says it: same class, same cause and hint, naming the component
            node_said = caught.value.__cause__
            assert isinstance(node_said, StepTimeout)
            hung = "component 'typed' (node 'typed-node'): the model hung at step 2"
            assert str(node_said).startswith(hung)
            expected = (
                "component 'typed' (node 'typed-node') hung at step 2 of episode 2 (t = 0.1 s): "
                "the FMU is stuck in a call, or slower than that; its process was stopped; "
                "the node killed its FMU process; reset() starts a fresh one"
            )
            assert str(caught.value) == f"system 'experiment' (1 components): {expected}"
            assert caught.value.detail == node_said.detail and caught.value.hint == node_said.hint
            assert caught.value.component == "typed"  # type: ignore[attr-defined]
            described = plain_info(own, "typed-node")
            assert described["health"] == "unusable" and described["counters"]["hung"] == 1
            assert gone(child)  # killed at the deadline
            assert fine_episode(env) == [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]]  # a fresh child
            assert plain_info(own, "typed-node")["health"] == "ok"
            (fresh,) = plant_processes(process)
            assert fresh.pid != child.pid
        stopped_s = stop(process)
        wait_until(lambda: gone(fresh), 10, "the component's FMU process to end")
        assert stopped_s < 15, stopped_s  # about 2 s; slack for a loaded machine


def test_sigterm_on_an_isolated_system_node_busy_in_a_step_leaves_no_process(
    net: Loopback, tmp_path: Path
) -> None:
    file = tmp_path / "typed_system.yaml"
    file.write_text(SYSTEM)
    own = own_net(net)
    with serve(file, own, "typed", extra=("--isolate", "--step-timeout", "60")) as process:
        (child,) = plant_processes(process)
        env = system_env(file, own, timeout_s=120)
        with busy_in_a_forked_step(env, child) as fork:
            assert plain_info(own, "typed-node")["health"] == "ok"  # mid-step, within its 60 s deadline
            stopped_s = stop(process)
            wait_until(lambda: gone(child) and gone(fork), 10, "the component's processes to end")
            assert stopped_s < 15, stopped_s  # about 2 s; slack for a loaded machine


def test_a_hung_component_in_a_system_node_without_isolation_is_reported_and_sigterm_exits(
    net: Loopback, tmp_path: Path
) -> None:
    file = tmp_path / "typed_system.yaml"
    file.write_text(SYSTEM)
    own = own_net(net)
    with serve(file, own, "typed", extra=("--step-timeout", "5")) as process:
        assert plant_processes(process) == []  # the FMU runs in the served process
        with system_env(file, own, timeout_s=60) as env:
            env.reset(options={"scenario": "hangs"})
            env.step(HALF)
            with pytest.raises(StepTimeout) as caught:
                env.step(HALF)
            message = str(caught.value)
            assert "component 'typed' (node 'typed-node') hung at step 2 of episode 1" in message, message
            assert "has not returned from step 2 of episode 1 for" in message, message
            assert message.endswith("; the node is unhealthy until restarted"), message
            assert plain_info(own, "typed-node")["health"] == "hung"
        stopped_s = stop(process)
        assert process.returncode == 3  # the native call cannot be interrupted: it leaves without it
        assert stopped_s < 15, stopped_s
        output = process.stdout.read() if process.stdout else ""
        assert "node 'typed-node': " in output and "exiting without it" in output, output


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_a_step_timeout_that_is_not_positive_is_refused_before_the_network(
    tmp_path: Path, value: str
) -> None:
    file = tmp_path / "typed_system.yaml"
    file.write_text(SYSTEM)
    nobody = "tcp/127.0.0.1:1"  # nothing listens: reaching the network would be a different error
    cmd = [sys.executable, "-m", "bridge.cli", "system", "serve", str(file), "--connect", nobody]
    done = subprocess.run(
        [*cmd, "--isolate", "--step-timeout", value], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 2, done.stderr
    assert f"--step-timeout must be > 0 seconds, got {float(value)}" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and "Zenoh" not in done.stderr
