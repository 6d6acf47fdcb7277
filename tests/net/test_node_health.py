"""A node's ``health`` says when its plant is unusable, and a node isolates one way whatever asks.

A node kept reporting ``health: ok`` while its FMU's instance was half-initialised after a refused
reset, or while its isolated child lay dead; isolation asked for by the file (``model.isolation``)
ran the in-process hang watchdog, declared the node unhealthy for good and left the child behind on
SIGTERM, where ``--isolate`` did not. Real ``fmu-bridge node`` processes on loopback; ``info`` is
read by a plain Zenoh query, as any client would.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pytest

from bridge.env import RemoteFmuEnv
from bridge.errors import StepError
from bridge.net import protocol as proto
from bridge.plant.base import MODEL_INIT_FAILED_HINT
from bridge.serving import experiment_node
from tests.conftest import Loopback, node_process, wait_until

pytestmark = pytest.mark.integration
TYPED = """\
model: {{fmu: 'example:typed', step_size: 0.1, episode_duration: 5.0{isolation}}}
actions: {{inputs: [real_in], low: {{real_in: -1}}, high: {{real_in: 1}}}}
observations: {{outputs: [real_out, counter]}}
reward: {{terms: [{{alive: 1.0}}]}}
scenarios:
  fine: {{parameters: {{real_param: 2.0}}}}
  refused: {{parameters: {{real_param: 5000.0}}}}
  forks: {{parameters: {{fault_at_step: 3, fault_kind: 4}}}}
schedule: {{mode: fixed}}
"""
HALF = np.array([0.5], dtype=np.float32)
# how the node isolates its FMU: not at all, by the file, by the flag
WAYS: dict[str, tuple[str, tuple[str, ...]]] = {
    "in_process": ("", ()),
    "file": (", isolation: {timeout: 60}", ()),
    "flag": ("", ("--isolate", "--step-timeout", "60")),
}


def experiment(tmp_path: Path, way: str) -> tuple[Path, tuple[str, ...]]:
    isolation, flags = WAYS[way]
    path = tmp_path / f"typed_{way}.yaml"
    path.write_text(TYPED.format(isolation=isolation))
    return path, flags


def plain_info(net: Loopback, node: str) -> dict[str, Any]:
    """The node's ``info`` reply through a bare Zenoh query: no bridge client in between (asked
    again until a node declared a moment ago is reachable through the router)."""
    answers: list[dict[str, Any]] = []

    def answered() -> bool:
        replies = net.session.get(proto.Keys(net.prefix, node).info, timeout=5.0)  # type: ignore[attr-defined]
        answers[:] = [json.loads(r.ok.payload.to_bytes()) for r in replies if r.ok is not None]
        return bool(answers)

    wait_until(answered, 10, f"an info reply from node {node!r}")
    assert len(answers) == 1, answers
    return answers[0]


def health(net: Loopback, node: str) -> tuple[str, str]:
    info = plain_info(net, node)
    return info["health"], info["health_detail"]


def plant_processes(node: subprocess.Popen[str]) -> list[psutil.Process]:
    """The node's isolated plant: the child multiprocessing spawned (not its resource tracker)."""
    children = psutil.Process(node.pid).children(recursive=True)
    return [p for p in children if "spawn_main" in " ".join(p.cmdline())]


def gone(process: psutil.Process) -> bool:
    try:
        return bool(process.status() == psutil.STATUS_ZOMBIE)  # this container's PID 1 may not reap
    except psutil.NoSuchProcess:
        return True


def run_fine(env: RemoteFmuEnv) -> list[list[float]]:
    env.reset(options={"scenario": "fine"})
    return [env.step(HALF)[0].tolist() for _ in range(3)]


FINE = [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]]


@contextlib.contextmanager
def busy_in_a_forked_step(env: Any, child: psutil.Process) -> Iterator[psutil.Process]:
    """Drive ``env`` (scenario ``forks``) in a thread until the isolated FMU process ``child`` and
    the fork its third step makes both spin in doStep; yield the fork. On leaving, the step must
    not have returned (the body stops the node under it)."""
    outcome: list[BaseException | None] = []

    def drive() -> None:
        try:
            env.reset(options={"scenario": "forks"})
            for _ in range(3):  # the third step forks; both processes spin in doStep
                env.step(HALF)
            outcome.append(None)
        except BaseException as exc:  # what the client says once the node is gone
            outcome.append(exc)

    driver = threading.Thread(target=drive, daemon=True)
    driver.start()
    wait_until(lambda: len(child.children()) == 1, 30, "the FMU's fork")
    (fork,) = child.children()
    spent = child.cpu_times().user + fork.cpu_times().user
    wait_until(lambda: child.cpu_times().user + fork.cpu_times().user > spent + 0.2, 30, "a busy step")
    yield fork
    driver.join(timeout=150)
    env.close()
    assert outcome and outcome[0] is not None, "the step returned although the node was stopped"


@pytest.mark.parametrize("way", ["in_process", "file"])
def test_a_refused_initialisation_shows_as_unusable_until_the_next_reset_heals_it(
    tmp_path: Path, loopback: Loopback, way: str
) -> None:
    path, flags = experiment(tmp_path, way)
    with (
        node_process(path, "healing", loopback, *flags),
        RemoteFmuEnv(path, "healing", session=loopback.session, prefix=loopback.prefix) as env,
    ):
        assert run_fine(env) == FINE
        assert health(loopback, "healing") == ("ok", "")
        with pytest.raises(StepError) as caught:  # what an in-process env raises (tests/plant/test_heal.py)
            env.reset(options={"scenario": "refused"})
        error = caught.value
        assert str(error).startswith(
            "node 'healing': the model's initialisation failed at reset of episode 2: "
            "typed: fmi2ExitInitializationMode failed"
        ), str(error)
        assert error.detail.endswith("; this reset set real_param = 5000.0"), error.detail
        assert error.hint == MODEL_INIT_FAILED_HINT
        assert "real_param = 5000 is above init_fails_above = 1000" in " ".join(error.log)
        state, detail = health(loopback, "healing")
        assert state == "unusable", (state, detail)
        assert ("initialisation failed" if way == "in_process" else "the last reset failed") in detail
        for _ in range(2):  # healed: the next episodes are exact
            assert run_fine(env) == FINE
            assert health(loopback, "healing") == ("ok", "")


@pytest.mark.parametrize("way", ["file", "flag"])
def test_an_isolated_child_that_died_shows_as_unusable_and_the_next_reset_starts_a_fresh_one(
    tmp_path: Path, loopback: Loopback, way: str
) -> None:
    path, flags = experiment(tmp_path, way)
    with (
        node_process(path, "orphaned", loopback, *flags) as node,
        RemoteFmuEnv(path, "orphaned", session=loopback.session, prefix=loopback.prefix) as env,
    ):
        assert run_fine(env) == FINE
        (child,) = plant_processes(node)
        child.kill()  # between two calls: the node has not talked to it since
        wait_until(lambda: health(loopback, "orphaned")[0] == "unusable", 10, "health: unusable")
        assert (
            "its process was killed by SIGKILL; the next reset() starts a fresh one"
            in health(loopback, "orphaned")[1]
        )
        assert run_fine(env) == FINE  # no failed reset first: the dead child is noticed before it
        assert health(loopback, "orphaned") == ("ok", "")
        assert [p.pid for p in plant_processes(node)] != [child.pid]


@pytest.mark.parametrize("way", list(WAYS))
def test_isolation_by_the_file_or_the_flag_is_the_same_node(
    tmp_path: Path, loopback: Loopback, way: str
) -> None:
    path, flags = experiment(tmp_path, way)
    isolate = "--isolate" in flags
    with experiment_node(
        path,
        name="same",
        options=loopback.options(),  # type: ignore[arg-type]
        prefix=loopback.prefix,
        isolate=isolate,
        step_timeout_s=60.0 if isolate else 7.0,
    ) as node:
        assert type(node.plant).__name__ == ("LocalFmuPlant" if way == "in_process" else "IsolatedFmuPlant")
        # isolated: the plant's own deadline bounds every call, no in-process watchdog thread
        assert node.watchdog.watching is (way == "in_process")
        info = plain_info(loopback, "same")
        assert info["isolated"] is (way != "in_process")
        assert info["step_timeout_s"] == (7.0 if way == "in_process" else 60.0)


@pytest.mark.parametrize("way", ["file", "flag"])
def test_sigterm_on_a_node_whose_child_is_busy_in_a_step_leaves_no_process(
    tmp_path: Path, loopback: Loopback, way: str
) -> None:
    path, flags = experiment(tmp_path, way)
    with node_process(path, "busy", loopback, *flags) as node:
        (child,) = plant_processes(node)
        env = RemoteFmuEnv(path, "busy", session=loopback.session, prefix=loopback.prefix, timeout_s=120)
        with busy_in_a_forked_step(env, child) as fork:
            assert plain_info(loopback, "busy")["health"] == "ok"  # mid-step, within its 60 s deadline
            node.send_signal(signal.SIGTERM)
            started = time.monotonic()
            node.wait(timeout=30)
            stopped_s = time.monotonic() - started
            wait_until(lambda: gone(child) and gone(fork), 10, "the plant's processes to end")
            assert stopped_s < 15, stopped_s  # about 2 s; slack for a loaded machine
