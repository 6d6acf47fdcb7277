"""Ownership, a hung FMU in a node, and the error paths that used to mislead (real subprocesses)."""

from __future__ import annotations

import signal
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bridge.env import RemoteFmuEnv, RemoteVecEnv
from bridge.env.fmu_env import FmuEnv
from bridge.errors import PlantDied, StepTimeout, TransportError
from bridge.experiment.examples import example_experiment
from bridge.net import protocol as proto
from bridge.net.remote import describe_nodes
from tests.conftest import Loopback, node_process, wait_until

pytestmark = pytest.mark.integration
CARTPOLE = example_experiment("cartpole_continuous")
ZERO = np.zeros(1, dtype=np.float32)
TYPED = """\
model: {fmu: 'example:typed', step_size: 0.1, episode_duration: 5.0}
actions: {inputs: [real_in], low: {real_in: -1}, high: {real_in: 1}}
observations: {outputs: [real_out, counter]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {}
  hangs: {parameters: {fault_at_step: 2, fault_kind: 1}}
schedule: {mode: fixed}
"""


def info(net: Loopback, node: str) -> dict[str, Any]:
    return describe_nodes(net.session, [node], prefix=net.prefix, timeout_s=10)[0]


def test_one_client_holds_a_node_until_another_takes_over_or_it_leaves(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "shared", loopback):
        first = RemoteFmuEnv(CARTPOLE, "shared", session=loopback.session, prefix=loopback.prefix)
        second = RemoteFmuEnv(CARTPOLE, "shared", session=loopback.session, prefix=loopback.prefix)
        try:
            first.reset(seed=0)
            first.step(ZERO)
            holder = f"{first.plant.client.client_id:016x}"  # type: ignore[attr-defined]
            assert info(loopback, "shared")["holder"]["client"] == holder
            with pytest.raises(
                TransportError, match=rf"busy.*node 'shared' is held by client {holder}.*take_over"
            ):
                second.reset(seed=1)
            taker = RemoteFmuEnv(
                CARTPOLE, "shared", session=loopback.session, prefix=loopback.prefix, take_over=True
            )
            taker.reset(seed=1)
            new = f"{taker.plant.client.client_id:016x}"  # type: ignore[attr-defined]
            with pytest.raises(TransportError, match=rf"not_holder: node 'shared' is held by client {new}"):
                first.step(ZERO)
            with FmuEnv(CARTPOLE) as local:  # the new holder's episode was not disturbed
                local.reset(seed=1)
                for _ in range(5):
                    np.testing.assert_array_equal(taker.step(ZERO)[0], local.step(ZERO)[0])
            taker.close()  # its token goes: the lease ends, the second client may reset without asking
            wait_until(lambda: info(loopback, "shared")["holder"] is None, 30, "the lease ending")
            second.reset(seed=2)
            assert info(loopback, "shared")["holder"]["client"] == f"{second.plant.client.client_id:016x}"  # type: ignore[attr-defined]
        finally:
            first.close()
            second.close()


@pytest.mark.parametrize(
    "isolation", ["", "flag", "file"], ids=["in_process", "isolated", "isolated_by_file"]
)
def test_a_hung_fmu_is_reported_and_the_node_stops_on_sigterm(
    loopback: Loopback, tmp_path: Path, isolation: str
) -> None:
    isolate = bool(isolation)
    experiment = tmp_path / "typed.yaml"
    # a 5 s deadline: the hang at step 2 meets it, and the reset and steps around it (a fresh FMU
    # process after the hang) keep well inside it on a loaded machine
    by_file = ", isolation: {timeout: 5}}" if isolation == "file" else "}"
    experiment.write_text(TYPED.replace("episode_duration: 5.0}", "episode_duration: 5.0" + by_file))
    extra = [
        "--step-timeout",
        "5" if isolation != "file" else "30",
        *(["--isolate"] if isolation == "flag" else []),
    ]
    with node_process(experiment, "stuck", loopback, *extra) as process:
        env = RemoteFmuEnv(
            experiment, "stuck", session=loopback.session, prefix=loopback.prefix, timeout_s=30
        )
        try:
            env.reset(seed=0, options={"scenario": "hangs"})
            env.step(ZERO)
            start = time.monotonic()
            with pytest.raises(StepTimeout, match=r"node 'stuck': the model hung at step 2"):
                env.step(ZERO)
            assert time.monotonic() - start < 20  # the node's 5 s deadline, not the client's 30 s
            described = info(loopback, "stuck")
            if isolate:  # the child was killed; the next reset starts a fresh one
                assert described["health"] == "unusable" and described["counters"]["hung"] == 1
                assert "no answer within 5 s" in described["health_detail"]
                assert "the next reset() starts a fresh process" in described["health_detail"]
                assert not list(
                    loopback.session.liveliness().get(  # type: ignore[attr-defined]
                        proto.Keys(loopback.prefix, "stuck").unhealthy, timeout=1.0
                    )
                )
                env.reset(seed=0, options={"scenario": "fine"})
                for _ in range(3):
                    env.step(ZERO)
                assert info(loopback, "stuck")["health"] == "ok"
            else:
                assert described["health"] == "hung" and "restart the node" in described["health_detail"]
                assert "has not returned from step 2 of episode 1 for" in described["health_detail"]
                tokens = [
                    str(r.ok.key_expr)
                    for r in loopback.session.liveliness().get(  # type: ignore[attr-defined]
                        proto.Keys(loopback.prefix, "stuck").unhealthy, timeout=2.0
                    )
                    if r.ok
                ]
                assert tokens, "no unhealthy liveliness token"
                with pytest.raises(PlantDied, match="unhealthy"):
                    env.reset(seed=0, options={"scenario": "fine"})
        finally:
            env.close()
        start = time.monotonic()
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=15)
        assert time.monotonic() - start < 12.0  # about 2 s; slack for a loaded machine


def test_a_reset_after_the_node_died_says_so_at_once(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "gone", loopback) as process:
        env = RemoteFmuEnv(CARTPOLE, "gone", session=loopback.session, prefix=loopback.prefix, timeout_s=30)
        try:
            env.reset(seed=0)
            process.send_signal(signal.SIGKILL)
            process.wait(timeout=10)
            start = time.monotonic()
            with pytest.raises(PlantDied) as caught:
                env.reset(seed=1)
            assert time.monotonic() - start < 15.0  # the death, not the 30 s timeout
            assert "within" not in str(caught.value) and "the plant died" in str(caught.value)
        finally:
            env.close()


def test_a_dead_node_is_reported_while_a_stopped_one_still_times_out(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "v-0", loopback) as stopped, node_process(CARTPOLE, "v-1", loopback) as dead:
        vec = RemoteVecEnv(
            CARTPOLE,
            ["v-0", "v-1"],
            session=loopback.session,
            prefix=loopback.prefix,
            timeout_s=30.0,
            on_error="raise",
        )
        try:
            vec.reset()
            vec.step(np.zeros((2, 1), dtype=np.float32))
            stopped.send_signal(signal.SIGSTOP)
            dead.send_signal(signal.SIGKILL)
            dead.wait(timeout=10)
            client = vec.envs[1].plant.client  # type: ignore[attr-defined]
            wait_until(lambda: not client.alive, 30, "v-1's liveliness token gone")
            start = time.monotonic()
            with pytest.raises(PlantDied, match="node 'v-1'"):
                vec.step(np.zeros((2, 1), dtype=np.float32))
            assert time.monotonic() - start < 20.0  # not after v-0's 30 s timeout
        finally:
            stopped.send_signal(signal.SIGCONT)
            vec.close()


def test_replace_dead_truncates_failed_model_steps_instead_of_aborting(loopback: Loopback) -> None:
    with node_process(CARTPOLE, "r-0", loopback):
        vec = RemoteVecEnv(
            CARTPOLE, "r-*", session=loopback.session, prefix=loopback.prefix, replace_dead=True
        )
        try:
            assert vec.on_error == "truncate"
        finally:
            vec.close()


def test_nodes_command_shows_health_and_holder_and_speaks_json(loopback: Loopback) -> None:
    import json
    import os
    import subprocess
    import sys

    with node_process(CARTPOLE, "held", loopback):
        env = RemoteFmuEnv(CARTPOLE, "held", session=loopback.session, prefix=loopback.prefix)
        try:
            env.reset(seed=0)
            holder = f"{env.plant.client.client_id:016x}"  # type: ignore[attr-defined]
            cmd = [sys.executable, "-m", "bridge.cli", "nodes", "--connect", loopback.endpoint]
            cmd += ["--prefix", loopback.prefix]
            run_env = {**os.environ, "COLUMNS": "250"}
            table = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=run_env, check=False)
            listed = subprocess.run(
                [*cmd, "--json"], capture_output=True, text=True, timeout=60, env=run_env, check=False
            )
        finally:
            env.close()
    assert table.returncode == 0 and listed.returncode == 0, table.stderr + listed.stderr
    entries = json.loads(listed.stdout)
    assert [e["node"] for e in entries] == ["held"] and entries[0]["health"] == "ok"
    assert entries[0]["holder"]["zid"] == str(loopback.session.zid())  # type: ignore[attr-defined]
    assert entries[0]["holder"]["client"] == holder and holder in table.stdout and "ok" in table.stdout
