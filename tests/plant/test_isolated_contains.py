"""Isolation that contains: forks, huge allocations, exit() and start failures of the FMU's process.

An FMU that forked once defeated the deadline and left a process per episode; a 4 GiB allocation
reached 3.25 GB resident under a 400 MB limit (checked only after the step); an FMU calling
``exit(0)`` was an unexplained death; a child that could not start was ``AssertionError: can only
join a started process``. The typed test model's ``fault_kind`` hooks 4, 5 and 6 do these things.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from bridge.env import FmuEnv
from bridge.errors import PlantDied, StepTimeout
from tests.conftest import Loopback, node_process, wait_until
from tests.plant.test_isolated import isolated_env

TYPED = """\
model: {fmu: 'example:typed', step_size: 0.1, episode_duration: 5.0}
actions: {inputs: [real_in], low: {real_in: -1}, high: {real_in: 1}}
observations: {outputs: [real_out, counter]}
reward: {terms: [{alive: 1.0}]}
scenarios:
  fine: {}
  forks: {parameters: {fault_at_step: 3, fault_kind: 4}}
  allocates: {parameters: {fault_at_step: 2, fault_kind: 5}}
  exits: {parameters: {fault_at_step: 3, fault_kind: 6}}
schedule: {mode: fixed}
"""
ZERO = np.zeros(1, dtype=np.float32)


@pytest.fixture(scope="module")
def typed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("contains") / "typed.yaml"
    path.write_text(TYPED)
    return path


def steps(env: FmuEnv, scenario: str, n: int) -> None:
    env.reset(seed=1, options={"scenario": scenario})
    for _ in range(n):
        env.step(ZERO)


def gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def test_an_fmu_that_forks_leaves_no_process_after_the_deadline(typed: Path) -> None:
    seen: set[int] = set()
    stop = threading.Event()
    with isolated_env(typed, timeout_s=5.0) as env:  # the fine reset and steps: well inside
        env.reset(seed=1, options={"scenario": "fine"})
        child = psutil.Process(env.plant._process.pid)  # type: ignore[attr-defined]

        def watch() -> None:  # the FMU's forked process, seen while the step hangs
            while not stop.is_set():
                try:
                    seen.update(p.pid for p in child.children(recursive=True))
                except psutil.NoSuchProcess:
                    return
                time.sleep(0.02)

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        try:
            with pytest.raises(StepTimeout, match="no answer within 5 s at step 3"):
                steps(env, "forks", 5)
        finally:
            stop.set()
            watcher.join(timeout=5)
        assert seen, "the FMU's fork was never seen: the hook did not run"
        wait_until(
            lambda: all(gone(p) for p in [child.pid, *seen]), 10, "the FMU's process and its fork to end"
        )
        steps(env, "fine", 5)  # and the next reset starts a fresh process


def test_a_4_gib_allocation_is_stopped_at_the_memory_limit(typed: Path) -> None:
    with isolated_env(typed, memory_limit_mb=400) as env:
        started = time.monotonic()
        with pytest.raises(
            PlantDied, match=r"at step 2 of episode 1: .*SIGABRT.*memory_limit_mb = 400"
        ) as caught:
            steps(env, "allocates", 5)
        assert time.monotonic() - started < 20, "the allocation was not refused at once"
        assert "caps the process's address space" in str(caught.value)
        steps(env, "fine", 5)


def test_an_fmu_calling_exit_is_plant_died_with_the_exit_code(typed: Path) -> None:
    with isolated_env(typed) as env:
        with pytest.raises(
            PlantDied, match=r"died at step 3 of episode 1: its process exited with code 0.*exit\(\)"
        ):
            steps(env, "exits", 5)
        steps(env, "fine", 5)


START_FAILS = textwrap.dedent(
    """
    import resource, sys
    from bridge.errors import PlantDied
    from bridge.experiment.config import load_experiment
    from bridge.plant.experiment_model import experiment_plant_spec
    from bridge.plant.isolated import IsolatedFmuPlant

    plant = IsolatedFmuPlant(experiment_plant_spec(load_experiment(sys.argv[1])))
    import os
    used = len(os.listdir("/proc/self/fd"))
    resource.setrlimit(resource.RLIMIT_NOFILE, (used + 1, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
    try:
        plant.bind(["real_in"], ["real_out"])
    except PlantDied as exc:
        print("PlantDied:", exc)
    """
)


def test_a_child_that_cannot_start_names_the_os_error(typed: Path) -> None:
    run = subprocess.run(
        [sys.executable, "-c", START_FAILS, str(typed)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ},
    )
    assert "PlantDied:" in run.stdout, run.stdout + run.stderr
    assert "the plant's process could not start" in run.stdout and "Too many open files" in run.stdout
    assert "AssertionError" not in run.stdout + run.stderr


@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGKILL"])
def test_a_stopped_node_leaves_no_fmu_process(tmp_path: Path, loopback: Loopback, signal_name: str) -> None:
    path = tmp_path / "isolated.yaml"
    path.write_text(
        TYPED.replace("episode_duration: 5.0}", "episode_duration: 5.0, isolation: {timeout: 5}}")
    )
    with node_process(path, "contained", loopback) as node:
        children = psutil.Process(node.pid).children(recursive=True)
        plants = [p for p in children if "multiprocessing" in " ".join(p.cmdline())]
        assert plants, [p.cmdline() for p in children]
        node.send_signal(getattr(signal, signal_name))
        node.wait(timeout=30)
        wait_until(lambda: all(gone(p.pid) for p in plants), 10, "the node's FMU processes to end")


IN_PROCESS = textwrap.dedent(
    """
    import sys
    import numpy as np
    from bridge.env import FmuEnv
    from bridge.experiment.config import load_experiment

    env = FmuEnv(load_experiment(sys.argv[1]))
    env.reset(seed=1, options={"scenario": sys.argv[2]})
    for _ in range(5):
        env.step(np.zeros(1, dtype=np.float32))
    print("finished")
    """
)


@pytest.mark.parametrize("scenario", ["exits", "fine"])
def test_an_fmu_calling_exit_in_process_does_not_end_it_silently_with_code_0(
    typed: Path, scenario: str
) -> None:
    run = subprocess.run(
        [sys.executable, "-c", IN_PROCESS, str(typed), scenario],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    if scenario == "fine":  # Python's own shutdown: the guard stays silent
        assert run.returncode == 0 and "finished" in run.stdout and "exit()" not in run.stderr, run.stderr
        return
    assert run.returncode == 70, (run.returncode, run.stdout, run.stderr)
    assert "finished" not in run.stdout
    assert "native code (an FMU loaded in this process) called exit()" in run.stderr
    assert "(exit status 0)" in run.stderr
