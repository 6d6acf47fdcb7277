"""Fixed-point iteration with components in nodes: rollback over the wire (real Zenoh, 127.0.0.1).

A node saves its FMU state when an action asks it to and goes back to it for a repeated macro
step, so the same system with iteration gives the in-process trajectory bit for bit with its
components in `fmu-bridge system serve` subprocesses. Nodes that cannot save, and actions that
ask for what the node cannot do, get errors that say so.
"""

from __future__ import annotations

import time
import uuid
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from bridge.env.fmu_env import FmuEnv
from bridge.errors import ConfigError, TransportError
from bridge.experiment.config import load_experiment
from bridge.models import example_fmu
from bridge.net import protocol as proto
from bridge.net.remote import describe_nodes
from bridge.net.system_node import NodeComponents
from bridge.plant.system.plant import SystemPlant
from bridge.serving.system import serve_components
from tests.conftest import Loopback, free_port
from tests.plant.test_system_nodes import NODES, remote_env, serve, system_file, trajectory

pytestmark = pytest.mark.integration
ITERATION = {"max_iterations": 8, "tolerance": 1e-13}


def iterated(directory: Path, name: str, nodes: dict[str, str], algorithm: str, **fmus: str) -> Path:
    """The example system with fixed-point iteration (and ``node:`` on the components in ``nodes``)."""
    path = system_file(directory, name, nodes, algorithm)
    data = yaml.safe_load(path.read_text())
    data["system"]["iteration"] = ITERATION
    for component, fmu in fmus.items():
        data["system"]["components"][component]["fmu"] = fmu
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def served(net: Loopback, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Every component of the example system in its own node (one serve process)."""
    directory = tmp_path_factory.mktemp("iteration_nodes")
    with serve(system_file(directory, "served", NODES), net):
        yield directory


def restored(net: Loopback) -> int:
    """How many repeated macro steps the component nodes have served (their own counters)."""
    nodes = describe_nodes(net.session, list(NODES.values()), prefix=net.prefix, timeout_s=10)
    return sum(int(d.get("counters", {}).get("restored", 0)) for d in nodes)


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss_seidel"])
@pytest.mark.parametrize("remote", [["motor"], ["controller", "motor", "load"]], ids=["mixed", "all"])
def test_iteration_in_nodes_gives_the_in_process_trajectory(
    served: Path, net: Loopback, algorithm: str, remote: list[str]
) -> None:
    here = iterated(served, f"here_{algorithm}", {}, algorithm)
    there = iterated(served, f"there_{algorithm}_{len(remote)}", {c: NODES[c] for c in remote}, algorithm)
    before = restored(net)
    with FmuEnv(here) as local, remote_env(there, net) as distributed:
        for seed in (1, 4):
            expected, got = trajectory(local, seed, steps=8), trajectory(distributed, seed, steps=8)
            np.testing.assert_array_equal(got, expected)
        master = local.plant.master  # type: ignore[attr-defined]
        assert master.last_iterations > 1 and distributed.plant.master.last_iterations > 1  # type: ignore[attr-defined]
    assert restored(net) > before  # the nodes really went back and repeated macro steps
    assert np.max(np.abs(expected)) > 1.0  # the motor really turned


def test_iteration_differs_from_the_explicit_coupling(served: Path, net: Loopback) -> None:
    """The repeated passes change the result (else the test above would prove nothing)."""
    plain = system_file(served, "plain_all", NODES)
    iterated_file = iterated(served, "iterated_all", NODES, "jacobi")
    with remote_env(plain, net) as explicit:  # one client at a time holds a node
        a = trajectory(explicit, 1, steps=8)
    with remote_env(iterated_file, net) as implicit:
        b = trajectory(implicit, 1, steps=8)
    assert not np.array_equal(a, b)
    np.testing.assert_allclose(a, b, rtol=0.2, atol=0.5)  # the same physics, a different coupling


def no_state_copy(directory: Path) -> Path:
    """The gearload FMU, its description saying it cannot get and set its state."""
    source = example_fmu("gearload", "2.0", "cs")
    target = directory / "gearload_nostate.fmu"
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                patched = data.replace(b'canGetAndSetFMUstate="true"', b'canGetAndSetFMUstate="false"')
                assert patched != data
                data = patched
            zout.writestr(item, data)
    return target


def test_a_component_that_cannot_save_its_state_is_named_here_and_in_a_node(
    net: Loopback, tmp_path: Path
) -> None:
    fmu = str(no_state_copy(tmp_path))
    here = iterated(tmp_path, "nostate_here", {}, "jacobi", load=fmu)
    with pytest.raises(
        ConfigError, match=r"component 'load' \(gearload_nostate.fmu\) cannot: the FMU cannot"
    ):
        FmuEnv(here)
    own = Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)
    there = iterated(tmp_path, "nostate_there", {"load": "nostate-load"}, "jacobi", load=fmu)
    with serve(there, own, "load"), pytest.raises(ConfigError) as caught:
        remote_env(there, own)
    message = str(caught.value)
    assert "component 'load' (node 'nostate-load') cannot: the FMU cannot get and set its state" in message
    assert "system.iteration" in message and str(there) in message


@pytest.fixture
def node_system(net: Loopback, tmp_path: Path) -> Iterator[tuple[SystemPlant, Loopback]]:
    """The example system with its motor in an in-process node, iteration on (for protocol tests)."""
    own = Loopback(net.endpoint, f"test_{uuid.uuid4().hex[:10]}", net.session)
    file = iterated(tmp_path, "proto", {"motor": "proto-motor"}, "jacobi")
    nodes = serve_components(load_experiment(file), session=net.session, prefix=own.prefix)
    remote = NodeComponents(session=net.session, prefix=own.prefix, timeout_s=30.0)
    plant = SystemPlant(load_experiment(file), remote=remote)
    try:
        yield plant, own
    finally:
        plant.close()
        for node in nodes:
            node.close()


def counters_once(net: Loopback, own: Loopback, ready: Callable[[dict[str, int]], Any]) -> dict[str, int]:
    """The node's counters once ``ready`` says so (or as they are after 30 s)."""
    deadline = time.monotonic() + 30
    while True:
        counters: dict[str, int] = describe_nodes(
            net.session, ["proto-motor"], prefix=own.prefix, timeout_s=10
        )[0]["counters"]
        if ready(counters) or time.monotonic() > deadline:
            return counters
        time.sleep(0.05)


def test_a_restore_the_node_cannot_serve_is_rejected_with_the_reason(
    node_system: tuple[SystemPlant, Loopback],
) -> None:
    plant, _ = node_system
    plant.bind(["controller.reference"], ["load.omega"])
    plant.reset({}, [10.0])
    motor = plant.plants["motor"]
    motor._flags = proto.RESTORE_STATE  # type: ignore[attr-defined]  # nothing saved yet
    with pytest.raises(
        TransportError, match=r"rejected step 1 of episode \d+: state: no state saved to restore"
    ):
        motor.step([1.0, 0.0])
    plant.reset({}, [10.0])  # the node serves on: a fresh episode iterates normally
    for _ in range(3):
        plant.step([10.0])
    assert plant.master.last_iterations > 1


def test_unknown_action_flags_and_negative_client_ids_are_malformed_and_never_stepped(
    node_system: tuple[SystemPlant, Loopback], net: Loopback
) -> None:
    plant, own = node_system
    plant.bind(["controller.reference"], ["load.omega"])
    plant.reset({}, [10.0])
    keys = proto.Keys(own.prefix, "proto-motor")
    holder = plant.plants["motor"].client.client_id  # type: ignore[attr-defined]
    key = plant.plants["motor"].client.key  # type: ignore[attr-defined]  # the holder's session
    action = proto.encode_values(proto.ACTION, 1, 1, holder, [1.0, 0.0], flags=1 << 10, key=key)
    net.session.put(keys.actions, action)  # type: ignore[attr-defined]
    state = proto.SAVE_STATE | proto.RESTORE_STATE
    both = proto.encode_values(proto.ACTION, 1, 1, holder, [1.0, 0.0], flags=state, key=key)
    net.session.put(keys.actions, both)  # type: ignore[attr-defined]
    negative = proto.encode_values(proto.ACTION, 1, 1, -holder, [1.0, 0.0])  # a plain step but the id
    net.session.put(keys.actions, negative)  # type: ignore[attr-defined]
    counters = counters_once(net, own, lambda c: c.get("malformed") == 2 and c.get("rejected_state"))
    assert counters.get("malformed") == 2 and counters.get("rejected_state") == 1, counters
    assert "steps" not in counters
    plant.step([10.0])  # and the holder steps on


def test_another_clients_reject_of_the_same_step_is_not_the_holders_answer(
    node_system: tuple[SystemPlant, Loopback], net: Loopback
) -> None:
    plant, own = node_system
    plant.bind(["controller.reference"], ["load.omega"])
    plant.reset({}, [10.0])
    motor = plant.plants["motor"]
    keys = proto.Keys(own.prefix, "proto-motor")
    intruder = motor.client.client_id ^ 2  # type: ignore[attr-defined]  # another client's id
    # the holder's next action is this step of this episode: another client sends it first
    action = proto.encode_values(proto.ACTION, motor.episode, motor.sample + 1, intruder, [1.0, 0.0])
    net.session.put(keys.actions, action)  # type: ignore[attr-defined]
    counters = counters_once(net, own, lambda c: c.get("rejected_not_holder"))
    assert counters.get("rejected_not_holder") == 1, counters
    # the reject (same episode and step) now waits in the holder's channel: it is not its answer
    for _ in range(3):
        plant.step([10.0])
    assert motor.sample > 1


def test_a_real_time_or_isolated_node_says_it_cannot_save(tmp_path: Path) -> None:
    from bridge.net.node import FmuNode
    from bridge.net.transport import ZenohOptions
    from bridge.plant.system.description import from_experiment
    from bridge.serving.system import component_served

    file = system_file(tmp_path, "rt", {"motor": "rt-motor"})
    experiment = load_experiment(file)
    motor = component_served(experiment, from_experiment(experiment), "motor")
    options = ZenohOptions(listen=(f"tcp/127.0.0.1:{free_port()}",))
    for kwargs, reason in (({"mode": "realtime", "rate": 0.0}, "real-time"), ({"isolate": True}, "isolated")):
        with FmuNode(motor.plant, motor.served, name="rt-motor", options=options, **kwargs) as node:  # type: ignore[arg-type]
            d = node.describe()
            assert d["can_save_state"] is False and reason in d["save_state_refusal"]


def test_a_recording_of_an_iterated_node_holds_the_accepted_pass_of_each_step(
    node_system: tuple[SystemPlant, Loopback], net: Loopback, tmp_path: Path
) -> None:
    """``record --node`` on the motor's node while the master repeats every macro step: the file
    holds one outputs and one actions message per macro step, the outputs the system took
    (read back by mcap)."""
    import threading

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from bridge.recording.node_recorder import NodeRecorder

    plant, own = node_system
    plant.bind(["controller.reference"], ["load.omega"])
    recorder = NodeRecorder(
        net.session, "proto-motor", tmp_path / "motor.mcap", prefix=own.prefix, timeout_s=30
    )
    thread = threading.Thread(target=recorder.run, daemon=True)
    thread.start()
    names = plant.plants["motor"].output_names
    taken, iterations, macro_steps = [], [], 12
    try:
        plant.reset({}, [10.0])
        taken.append(plant.master.outputs["motor"].copy())
        for _ in range(macro_steps):
            plant.master.step()
            taken.append(plant.master.outputs["motor"].copy())
            iterations.append(plant.master.last_iterations)
        counters = describe_nodes(net.session, ["proto-motor"], prefix=own.prefix, timeout_s=10)[0][
            "counters"
        ]
        wanted = {"outputs": counters["steps"] + counters["resets"], "actions": counters["steps"]}
        repeats = 2 * (counters["steps"] - macro_steps)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (  # a frame is counted before it is held: wait for both
            any(recorder.stats.frames.get(t, 0) < n for t, n in wanted.items())
            or recorder.stats.repeated < repeats
        ):
            time.sleep(0.05)
    finally:
        recorder.stop()
        thread.join(timeout=30)
        path = recorder.close()
    assert min(iterations) > 1 and counters["restored"] > 0  # the node really repeated steps
    assert recorder.stats.frames == wanted
    assert recorder.stats.repeated == repeats

    found: dict[str, list[tuple[int, dict[str, float]]]] = {"/outputs": [], "/actions": []}
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, m in reader.iter_decoded_messages(log_time_order=True):
            if channel.topic in found:
                stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                found[channel.topic].append((stamp, dict(zip(m.name, m.position))))
    macro_ns = round(recorder.description["sampling_time_s"] * 1e9)
    start_ns = round(recorder.description["start_time_s"] * 1e9)
    outputs, actions = found["/outputs"], found["/actions"]
    # each reset of the initialisation puts its step 0 on the wire; the last one starts the run
    assert len(outputs) == counters["resets"] + macro_steps and len(actions) == macro_steps
    assert [s for s, _ in outputs[-len(taken) :]] == [start_ns + k * macro_ns for k in range(len(taken))]
    assert [s for s, _ in actions] == [start_ns + k * macro_ns for k in range(macro_steps)]
    for (_, recorded), expected in zip(outputs[-len(taken) :], taken):
        assert set(names) <= set(recorded)
        np.testing.assert_allclose([recorded[n] for n in names], expected, rtol=0, atol=1e-12)
    assert np.ptp([recorded["omega"] for _, recorded in outputs]) > 1.0  # the motor really turned
