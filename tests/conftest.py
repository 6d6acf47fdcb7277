"""Shared fixtures: real FMUs built once per session (ours with gcc, others by their exporters)."""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from tiers import build_step

DATA = Path(__file__).parent / "data"

# One math thread for torch and numpy's BLAS, here and in every subprocess the tests start
# (trainers, the demo, nodes). The networks trained here are small; with the default pool, two
# spinning threads per process on a shared 2-core machine measured 16 PPO steps/s against
# 650-700 with one thread, and a test that passes only on a quiet machine is a broken test.
for _variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")


def _build_each_cli_once() -> None:
    """typer's ``CliRunner.invoke`` turns the Typer app into its click command anew on every call
    (every option's annotations evaluated again): 0.1-0.2 s for this CLI, more than most commands
    under test take, and the recording soaks invoke it thousands of times. Built once per app
    (and per set of registered commands) and process here: the command a console script builds
    once per run. Without ``typer.testing._get_command`` (another typer) the runner is left as is."""
    import typer.main
    import typer.testing

    build = typer.main.get_command
    built: dict[tuple[int, int, int], tuple[object, Any]] = {}

    def command(app: typer.Typer) -> Any:
        key = (id(app), len(app.registered_commands), len(app.registered_groups))
        held = built.get(key)
        if held is None or held[0] is not app:
            built[key] = held = (app, build(app))
        return held[1]

    if hasattr(typer.testing, "_get_command"):
        typer.testing._get_command = command


_build_each_cli_once()


@pytest.fixture(scope="session", autouse=True)
def _one_torch_thread() -> None:
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


def wait_until(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Poll ``condition`` until it holds; fail naming ``what`` after ``timeout_s`` (a loaded
    machine gets the whole timeout, a quiet one returns as soon as the condition holds)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout_s} s")
        time.sleep(0.01)


def wait_for(probe: Callable[[], Any], timeout_s: float = 30.0, what: str = "the condition") -> Any:
    """:func:`wait_until` for a probe whose truthy value the caller wants: poll it until it is
    truthy and return that value; fail naming ``what`` and the last value after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not (value := probe()):
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout_s} s (last: {value!r})")
        time.sleep(0.01)
    return value


def run_pytest(
    args: Sequence[str], basetemp: Path, env: Mapping[str, str], timeout_s: float
) -> subprocess.CompletedProcess[str]:
    """A pytest session over ``args`` in a fresh interpreter from the repository's root (its own
    ``--basetemp``, no cache), for what only a new process shows: environment variables read at
    import, end-of-session hooks."""
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--basetemp", str(basetemp), *args],
        cwd=Path(__file__).resolve().parents[1],
        env=dict(env),
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )


def example_fmu(name: str, fmi_version: str, interface: str) -> Path:
    from bridge.models import example_fmu as build

    return build(name, fmi_version, interface)


def _cache_dir() -> Path:
    root = Path(os.environ.get("FMU_BRIDGE_CACHE", Path.home() / ".cache" / "fmu-bridge"))
    path = root / "thirdparty"
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture(scope="session")
def cartpole_fmu() -> Path:
    return example_fmu("cartpole", "2.0", "cs")


@pytest.fixture(scope="session")
def cartpole_fmu3() -> Path:
    return example_fmu("cartpole", "3.0", "cs")


@pytest.fixture(scope="session")
def dcmotor_fmu() -> Path:
    return example_fmu("dcmotor", "2.0", "cs")


@pytest.fixture(scope="session")
def typed_fmu2() -> Path:
    return example_fmu("typed", "2.0", "cs")


@pytest.fixture(scope="session")
def typed_fmu3() -> Path:
    return example_fmu("typed", "3.0", "cs")


def _pythonfmu_build(
    tool: str,
    source: Path,
    out: Path,
    *,
    files: Sequence[Path] = (),
    env: dict[str, str] | None = None,
    flags: Sequence[str] = (),
) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", tool, "build", "-f", str(source), "-d", str(out), *flags, *map(str, files)]
    with build_step():
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False, env=env)
    if result.returncode != 0:
        pytest.fail(f"{tool} could not export {source.name}:\n{result.stdout}\n{result.stderr}")
    return out / f"{source.stem}.fmu"


@pytest.fixture(scope="session")
def pythonfmu_heater2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An FMI 2.0 co-simulation FMU exported by pythonfmu (a tool we did not write)."""
    pytest.importorskip("pythonfmu")
    return _pythonfmu_build("pythonfmu", DATA / "slaves" / "Heater2.py", tmp_path_factory.mktemp("pyfmu2"))


@pytest.fixture(scope="session")
def pythonfmu_heater3(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An FMI 3.0 co-simulation FMU exported by pythonfmu3 (a tool we did not write)."""
    pytest.importorskip("pythonfmu3")
    return _pythonfmu_build("pythonfmu3", DATA / "slaves" / "Heater3.py", tmp_path_factory.mktemp("pyfmu3"))


@pytest.fixture(scope="session")
def pythonfmu_longrun2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pythonfmu's export of tests/data/slaves/LongRun2.py: a default experiment of 1e8 s at 0.01 s."""
    pytest.importorskip("pythonfmu")
    return _pythonfmu_build("pythonfmu", DATA / "slaves" / "LongRun2.py", tmp_path_factory.mktemp("longrun2"))


def unimportable_fmu(tool: str, out: Path, requirements: str | None = None) -> Path:
    """A pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0) export whose class import fails when it runs.

    Its module imports ``fmu_bridge_absent_package``, which exists only while it is exported (a
    package made for the build in ``out``); ``requirements`` becomes the FMU's
    ``resources/requirements.txt``.
    """
    pytest.importorskip(tool)
    stand_in = out / "build-path" / "fmu_bridge_absent_package"
    stand_in.mkdir(parents=True, exist_ok=True)
    (stand_in / "__init__.py").write_text("")
    files = []
    if requirements is not None:
        files.append(out / "requirements.txt")
        files[0].write_text(requirements)
    path = os.pathsep.join([str(stand_in.parent), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    source = DATA / "slaves" / ("Unimportable2.py" if tool == "pythonfmu" else "Unimportable3.py")
    return _pythonfmu_build(tool, source, out / "fmu", files=files, env=env)


@pytest.fixture(scope="session")
def eta_ctrl_fmus() -> dict[str, Path]:
    """Dymola-exported FMI 2.0 FMUs shipped in eta-ctrl's source distribution (fetched once, cached)."""
    cache = _cache_dir() / "eta-ctrl"
    wanted = {
        "damped_oscillator": "examples/damped_oscillator/damped_oscillator.fmu",
        "kea_simplified": "examples/kea_simplified/kea_simplified.fmu",
    }
    found = {name: cache / Path(rel).name for name, rel in wanted.items()}
    if all(p.is_file() for p in found.values()):
        return found
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "-q",
        "--no-deps",
        "--no-binary",
        ":all:",
        "eta-ctrl==0.4.0",
        "-d",
        str(cache),
    ]
    try:
        with build_step():
            subprocess.run(cmd, capture_output=True, timeout=180, check=True)
    except (subprocess.SubprocessError, OSError) as exc:
        pytest.skip(f"eta-ctrl's source distribution could not be downloaded (offline?): {exc}")
    archives = sorted(cache.glob("eta_ctrl-*.tar.gz"))
    if not archives:
        pytest.skip("eta-ctrl's source distribution is not in the package index")
    with tarfile.open(archives[-1]) as tar:
        for member in tar.getmembers():
            for name, rel in wanted.items():
                if member.name.endswith(rel):
                    data = tar.extractfile(member)
                    assert data is not None
                    found[name].write_bytes(data.read())
    missing = [n for n, p in found.items() if not p.is_file()]
    if missing:
        pytest.skip(f"eta-ctrl's source distribution no longer ships {missing}")
    return found


# -- Zenoh on loopback: explicit endpoints, no multicast scouting, a unique prefix per test -------
import contextlib  # noqa: E402
import os as _os  # noqa: E402
import socket  # noqa: E402
import uuid  # noqa: E402
from collections.abc import Iterator  # noqa: E402
from dataclasses import dataclass  # noqa: E402


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class Loopback:
    endpoint: str
    prefix: str
    session: object

    def options(self) -> object:
        from bridge.net.transport import ZenohOptions

        return ZenohOptions(connect=(self.endpoint,))


@contextlib.contextmanager
def router_on_loopback() -> Iterator[Loopback]:
    """A Zenoh router session on a free 127.0.0.1 port and a key prefix of its own: nodes and
    CLI sessions connect to it."""
    from bridge.net.transport import ZenohOptions, open_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohOptions(mode="router", listen=(endpoint,)))
    try:
        yield Loopback(endpoint, f"test_{uuid.uuid4().hex[:10]}", session)
    finally:
        session.close()  # type: ignore[attr-defined]


@pytest.fixture
def loopback() -> Iterator[Loopback]:
    """A router on loopback for one test (:func:`router_on_loopback`)."""
    with router_on_loopback() as net:
        yield net


@contextlib.contextmanager
def node_process(
    experiment: Path | str, name: str, net: Loopback, *extra: str
) -> Iterator[subprocess.Popen[str]]:
    """``fmu-bridge node`` as a real subprocess, stopped (and reaped) at the end."""
    cmd = [
        sys.executable,
        "-m",
        "bridge.cli",
        "node",
        str(experiment),
        "--name",
        name,
        "--connect",
        net.endpoint,
        "--prefix",
        net.prefix,
        *extra,
    ]
    process = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**_os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        _wait_for_line(process, "serving", timeout_s=60)
        _wait_for_node(net, name, timeout_s=30)
        yield process
    finally:
        stop_process(process, timeout_s=10)


def stop_process(process: subprocess.Popen[str], timeout_s: float) -> None:
    """SIGTERM, SIGKILL if it does not exit within ``timeout_s``, reaped, its pipe closed."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=timeout_s)
    if process.stdout is not None:
        process.stdout.close()


def _wait_for_line(process: subprocess.Popen[str], text: str, timeout_s: float) -> None:
    assert process.stdout is not None
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        seen.append(line)
        if text in line:
            return
    process.kill()
    pytest.fail(f"node did not start within {timeout_s} s:\n{''.join(seen)}")


def _wait_for_node(net: Loopback, name: str, timeout_s: float) -> None:
    from bridge.net.remote import list_nodes

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if name in list_nodes(net.session, prefix=net.prefix, timeout_s=0.5):
            return
        time.sleep(0.05)
    pytest.fail(f"node {name!r} did not appear under {net.prefix}/ within {timeout_s} s")


def recorder_counts(net: Loopback, node: str) -> dict[str, Any] | None:
    """The counts of the ``fmu-bridge record --node`` recorder of ``node`` (None while none answers)."""
    import json

    for reply in net.session.get(f"{net.prefix}/{node}/recorders/*", timeout=2.0):  # type: ignore[attr-defined]
        if reply.ok is not None:
            counts: dict[str, Any] = json.loads(reply.ok.payload.to_bytes())
            return counts
    return None


def wait_for_recorder(net: Loopback, node: str, timeout_s: float = 60.0) -> None:
    """Until the recorder of ``node`` answers. It declares its subscriptions before its queryable,
    and every later query to the node (a remote env's info and reset) follows those declarations
    on the same links, so the node routes its frames to the recorder from then on."""
    wait_until(lambda: recorder_counts(net, node) is not None, timeout_s, "the recorder starting")


def wait_for_recorded(net: Loopback, node: str, frames: dict[str, int], timeout_s: float = 60.0) -> None:
    """Until the recorder of ``node`` has taken in at least ``frames[topic]`` frames per topic."""

    def done() -> bool:
        counts = recorder_counts(net, node)
        return counts is not None and all(counts["frames"].get(t, 0) >= n for t, n in frames.items())

    wait_until(done, timeout_s, f"the recorder taking in {frames} frames")


@pytest.fixture(scope="session")
def balancer(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A PPO run that balances the cart-pole FMU (RL Zoo settings; 500/500 from about 20k steps),
    trained once per session for the deployment tests."""
    from agents.train import train
    from bridge.experiment.examples import example_experiment

    def trained(run: Path) -> Path:
        overrides = {"timesteps": 60_000, "eval_every": 1_000_000}
        train(example_experiment("cartpole_balance"), overrides=overrides, run_dir=run, progress=False)
        return run

    run = tmp_path_factory.mktemp("deploy") / "ppo"
    return shared_by_workers("balancer", tmp_path_factory, trained, run)


def shared_by_workers(
    name: str, factory: pytest.TempPathFactory, make: Callable[[Path], Path], into: Path
) -> Path:
    """``make(folder)`` once per test run, whatever the number of pytest-xdist workers: the first
    worker that needs it makes it (the others wait on a lock, which costs no CPU the maker could
    use) and every worker gets its own copy at ``into`` (tests may write into theirs). Without
    xdist, ``make(into)``. ``FMU_BRIDGE_TEST_SHARED`` names a folder that keeps what was made for
    the test runs after (CI: the ROS venv's tests take the policy its pinned tiers trained)."""
    import fcntl
    import shutil

    kept = os.environ.get("FMU_BRIDGE_TEST_SHARED")
    if kept:
        shared = Path(kept) / name
    elif os.environ.get("PYTEST_XDIST_TESTRUNUID") is not None:
        shared = factory.getbasetemp().parent / f"shared-{name}"  # the run's folder above every worker's
    else:
        return make(into)
    shared.mkdir(parents=True, exist_ok=True)
    with (shared / "lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        made = shared / "made"
        if not (shared / "done").exists():
            shutil.rmtree(made, ignore_errors=True)  # a maker that failed left a part
            make(made)
            (shared / "done").touch()
    shutil.copytree(made, into)
    return into


if TYPE_CHECKING:
    from bridge.experiment.config import Experiment
    from bridge.fmu.vocab import ModelInfo


def check_with_model(experiment: Experiment) -> ModelInfo:
    """``check_experiment`` against the model the experiment names (read from its FMU or system)."""
    from bridge.experiment.validate import check_experiment
    from bridge.plant.factory import model_info_for

    return check_experiment(experiment, model_info_for(experiment))


def pytest_configure(config: pytest.Config) -> None:
    """The fuzz and fault tests' counts go to a temporary folder of this session (see
    tests/reliability_table.py: committed into docs/ only on request)."""
    from reliability_table import counts_dir

    counts_dir()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tier markers from what each test does (tests/tiers.py); the default run is the fast tier."""
    from tiers import mark_tiers

    mark_tiers(items)
    # The slow tier's tests first (a stable sort: each tier in its own order): where one run takes
    # several tiers on several workers (CI), the longest tests start at once instead of last.
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    """A fast-tier test that starts a process fails, naming the marker it needs (tests/tiers.py)."""
    from tiers import guard_fast_tier

    return (yield from guard_fast_tier(item))


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """reliability.md beside the counts the fuzz and fault tests wrote in this run."""
    from reliability_table import write

    written = write()
    if written is not None:
        session.config.stash[_RELIABILITY] = written


_RELIABILITY = pytest.StashKey[Path]()


def pytest_terminal_summary(
    terminalreporter: pytest.TerminalReporter, exitstatus: int, config: pytest.Config
) -> None:
    written = config.stash.get(_RELIABILITY, None)
    if written is not None:
        terminalreporter.write_line(
            f"reliability counts: {written} (FMU_BRIDGE_WRITE_RELIABILITY=1 writes them to docs/ instead)"
        )


@pytest.fixture(scope="session")
def names2(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pythonfmu's export of tests/data/slaves/Names2.py: locals only, Modelica-style names."""
    pytest.importorskip("pythonfmu")
    return _pythonfmu_build("pythonfmu", DATA / "slaves" / "Names2.py", tmp_path_factory.mktemp("names2"))


@pytest.fixture(scope="session")
def arrays3_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """pythonfmu3's export of tests/data/slaves/Arrays3.py: FMI 3.0 arrays u[3], k[3] in, y[2,3] out."""
    pytest.importorskip("pythonfmu3")
    return _pythonfmu_build("pythonfmu3", DATA / "slaves" / "Arrays3.py", tmp_path_factory.mktemp("arr3"))
