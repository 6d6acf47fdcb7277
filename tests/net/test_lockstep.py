"""The lockstep rules of a node as plain unit tests: no Zenoh, no subprocess, no sleep."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from bridge.net import lockstep as ls
from bridge.net import protocol as proto
from bridge.net.handshake import KeyPair, reply_proof, request_proof
from bridge.net.lease import Lease

HOLDER, OTHER = 0x1111, 0x2222
STATE_OK = None


def in_range(values: Sequence[float]) -> str | None:
    return None if all(-1.0 <= v <= 1.0 for v in values) else f"{list(values)} is outside [-1, 1]"


def held() -> Lease:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    assert lease.acquire(HOLDER, "zid", False, pub=KeyPair().public).refusal is None
    return lease


def granted(lease: Lease, client: int, payload: bytes = b"{}", take_over: bool = False) -> bytes:
    """Start a lease for ``client`` as NodeClient does; the session key the client derives."""
    pair = KeyPair()
    admission = lease.acquire(client, "zid", take_over, pub=pair.public, payload=payload)
    assert admission.refusal is None and len(admission.node_pub) == 32
    pub = admission.node_pub
    return pair.session_key(pub, client_pub=pair.public, node_pub=pub, client=client)


def action(
    state: ls.Lockstep, episode: int, step: int, *, client: int = HOLDER, values: Sequence[float] = (0.5,),
    flags: int = 0, signed: bool = True,
) -> bytes:  # fmt: skip
    """An ACTION payload, signed with the session key when ``signed`` (as the holder signs)."""
    key = state.lease.key if signed else None
    return proto.encode_values(proto.ACTION, episode, step, client, list(values), flags=flags, key=key)


def started(episode: int = 3) -> ls.Lockstep:
    """Episode ``episode`` held by HOLDER, stepped once (step 1 done, step 2 next)."""
    state = ls.Lockstep(held(), in_range)
    state.started(episode, b"step-0")
    first = action(state, episode, 1)
    state.stepped((HOLDER, first[proto.HEADER.size :]), [0.0], 1_000, terminated=False)
    return state


def verdict(
    state: ls.Lockstep,
    episode: int,
    step: int,
    *,
    client: int = HOLDER,
    values: Sequence[float] = (0.5,),
    flags: int = 0,
    refusal: str | None = STATE_OK,
    signed: bool = True,
) -> ls.Step | ls.Reject:
    payload = action(state, episode, step, client=client, values=values, flags=flags, signed=signed)
    sent = flags | (proto.SIGNED if signed and state.lease.key is not None else 0)
    refused = state.admit(client, values, sent, refusal, payload)
    if refused is not None:
        return refused
    return state.order(episode, step, sent, (client, payload[proto.HEADER.size :]))


def reason(result: ls.Step | ls.Reject) -> str:
    assert isinstance(result, ls.Reject), f"expected a reject, got {result}"
    assert result.reason in ls.REASONS
    return result.reason


@pytest.mark.parametrize(
    ("case", "kwargs", "expected"),
    [
        ("stale: another episode", {"episode": 2, "step": 2}, ls.STALE),
        ("stale: a future episode", {"episode": 4, "step": 1}, ls.STALE),
        ("out of order: a step ahead", {"episode": 3, "step": 3}, ls.OUT_OF_ORDER),
        ("out of order: a step behind", {"episode": 3, "step": 0}, ls.OUT_OF_ORDER),
        (
            "conflict: the last step with other values",
            {"episode": 3, "step": 1, "values": (0.25,)},
            ls.CONFLICT,
        ),
        ("not holder", {"episode": 3, "step": 2, "client": OTHER}, ls.NOT_HOLDER),
        ("anonymous while held", {"episode": 3, "step": 2, "client": 0}, ls.NOT_HOLDER),
        ("out of range", {"episode": 3, "step": 2, "values": (1.5,)}, ls.OUT_OF_RANGE),
        ("NaN is out of range", {"episode": 3, "step": 2, "values": (float("nan"),)}, ls.OUT_OF_RANGE),
        (
            "state: save and restore at once",
            {"episode": 3, "step": 2, "flags": proto.SAVE_STATE | proto.RESTORE_STATE},
            ls.STATE,
        ),
        (
            "state: the node cannot save",
            {"episode": 3, "step": 2, "flags": proto.SAVE_STATE, "refusal": "no"},
            ls.STATE,
        ),
    ],
)
def test_the_reject_table(case: str, kwargs: dict[str, Any], expected: str) -> None:
    state = started()
    assert reason(verdict(state, **kwargs)) == expected, case
    assert (state.episode, state.step, state.ended) == (3, 1, False)  # a reject changes nothing


def test_the_holders_check_comes_first_then_the_values_then_the_health() -> None:
    state = started()
    state.unhealthy = "the FMU hung"
    assert reason(verdict(state, 3, 2, client=OTHER, values=(9.0,))) == ls.NOT_HOLDER
    assert reason(verdict(state, 3, 2, values=(9.0,))) == ls.OUT_OF_RANGE
    refused = verdict(state, 3, 2)
    assert reason(refused) == ls.UNHEALTHY and isinstance(refused, ls.Reject) and "hung" in refused.detail
    assert not state.plain(3, 2, HOLDER, [0.5], action(state, 3, 2))


def test_an_inactive_managed_node_steps_for_nobody_and_says_why() -> None:
    state = started()
    state.inactive = "the managed node is not active"
    assert not state.plain(3, 2, HOLDER, [0.5], action(state, 3, 2))
    refused = verdict(state, 3, 2)  # the holder's plain next step, in range
    assert reason(refused) == ls.INACTIVE and isinstance(refused, ls.Reject)
    assert "not active" in refused.detail and (state.step, state.ended) == (1, False)
    # deactivated between admission and the lock: the order refuses it too
    assert reason(state.order(3, 2, proto.SIGNED, (HOLDER, b""))) == ls.INACTIVE
    state.inactive = ""  # activated again: the same step is served
    assert verdict(state, 3, 2) == ls.ADVANCE and state.plain(3, 2, HOLDER, [0.5], action(state, 3, 2))


def test_a_duplicate_of_the_last_step_is_a_retry_never_a_second_step() -> None:
    state = started()
    assert verdict(state, 3, 1) == ls.RETRY
    assert state.last_frame.startswith(
        proto.HEADER.pack(proto.VERSION, proto.OUTPUTS, proto.SIGNED, 3, 1, 1_000)
    )
    assert state.step == 1


def test_the_next_step_advances_and_an_ended_episode_refuses_more() -> None:
    state = started()
    assert verdict(state, 3, 2) == ls.ADVANCE
    assert state.plain(3, 2, HOLDER, [0.5], action(state, 3, 2))
    frame = state.stepped((HOLDER, action(state, 3, 2)[proto.HEADER.size :]), [0.25], 2_000, terminated=True)
    decoded = proto.decode(frame)
    assert (decoded.episode, decoded.step, decoded.terminated, decoded.floats) == (3, 2, True, (0.25,))
    assert reason(verdict(state, 3, 3)) == ls.ENDED
    assert not state.plain(3, 3, HOLDER, [0.5], action(state, 3, 3))
    state.started(4, b"step-0")
    assert verdict(state, 4, 1) == ls.ADVANCE


def test_a_failed_step_ends_the_episode_and_its_retry_gets_the_error_again() -> None:
    state = started()
    frame = state.failed(
        (HOLDER, action(state, 3, 2)[proto.HEADER.size :]), "the model failed", 1_000, hung=True
    )
    decoded = proto.decode(frame)
    assert decoded.kind == proto.ERROR and decoded.flags == proto.FAILED | proto.HUNG | proto.SIGNED
    assert (decoded.step, decoded.sim_time_ns) == (2, 1_000)  # the time the step started at, not 0
    assert verdict(state, 3, 2) == ls.RETRY and state.last_frame == frame
    assert reason(verdict(state, 3, 3)) == ls.ENDED


def test_a_restore_makes_the_step_it_names_the_next_one_again() -> None:
    state = started()
    state.stepped((HOLDER, action(state, 3, 2)[proto.HEADER.size :]), [0.0], 2_000, terminated=False)
    order = verdict(state, 3, 2, flags=proto.RESTORE_STATE)
    assert order == ls.Step(restore=True)
    state.restored(2)
    assert state.next(2, 0) == ls.ADVANCE and (state.step, state.last_frame) == (1, b"")
    save = verdict(state, 3, 2, flags=proto.SAVE_STATE)
    assert save == ls.Step(save=True)


def test_the_fast_path_accepts_exactly_the_plain_next_step() -> None:
    state = started()
    assert state.plain(3, 2, HOLDER, [0.5], action(state, 3, 2))
    for episode, step, client, values in [
        (2, 2, HOLDER, [0.5]),
        (3, 3, HOLDER, [0.5]),
        (3, 1, HOLDER, [0.5]),
        (3, 2, OTHER, [0.5]),
        (3, 2, -1, [0.5]),
        (3, 2, HOLDER, [2.0]),
    ]:
        payload = action(state, episode, step, client=client, values=values)
        assert not state.plain(episode, step, client, values, payload), (episode, step, client, values)
        sender = client if client >= 0 else OTHER
        assert verdict(state, episode, step, client=sender, values=values) != ls.ADVANCE


def test_nobody_holds_a_fresh_node_so_anyone_may_step_it_and_the_reject_frame_names_its_client() -> None:
    state = ls.Lockstep(Lease("n"), in_range)
    state.started(1, b"")
    assert verdict(state, 1, 1, client=0) == ls.ADVANCE
    frame = proto.decode(ls.Reject(ls.STALE, "old").frame(7, 8, OTHER, None))
    assert (frame.kind, frame.episode, frame.step, frame.sim_time_ns) == (proto.REJECT, 7, 8, OTHER)
    assert frame.message == "stale: old"


# -- sessions: the holder proves itself on every action and reset ---------------------------------------
def test_a_peer_with_the_holders_id_but_not_its_session_key_is_not_the_holder() -> None:
    state = started()
    genuine = action(state, 3, 2)
    forged = bytearray(genuine)
    forged[proto.HEADER.size + proto.COUNT.size] ^= 1  # other values under the holder's MAC
    assert not state.lease.allows(HOLDER, bytes(forged)) and state.lease.allows(HOLDER, genuine)
    unsigned = action(state, 3, 2, signed=False)
    assert reason(state.admit(HOLDER, [0.5], 0, None, unsigned) or ls.ADVANCE) == ls.NOT_HOLDER
    other_key = proto.encode_values(proto.ACTION, 3, 2, HOLDER, [0.5], key=bytes(proto.KEY_SIZE))
    assert not state.lease.allows(HOLDER, other_key)
    reject = ls.Reject(ls.NOT_HOLDER, "x")
    assert state.reject_key(reject, HOLDER, unsigned) is None  # unsigned: the holder ignores it
    assert state.reject_key(ls.Reject(ls.STALE, "x"), HOLDER, genuine) == state.lease.key


def test_a_lease_needs_a_live_token_and_ends_with_it() -> None:
    lease = Lease("n")
    refusal = lease.acquire(OTHER, "zid", False, pub=KeyPair().public).refusal
    assert refusal is not None and "no liveliness token" in refusal and lease.holder is None
    lease.token(OTHER, alive=True)
    assert granted(lease, OTHER) == lease.key
    assert lease.token(OTHER, alive=False) and lease.holder is None


def test_the_session_key_is_agreed_on_both_sides_and_never_in_a_reply() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    pair = KeyPair()
    admission = lease.acquire(HOLDER, "zid", False, pub=pair.public, payload=b"grant")
    key = pair.session_key(
        admission.node_pub, client_pub=pair.public, node_pub=admission.node_pub, client=HOLDER
    )
    assert key == lease.key and key not in admission.node_pub
    thief = KeyPair()  # who captured both public keys derives another key
    other = thief.session_key(
        admission.node_pub, client_pub=pair.public, node_pub=admission.node_pub, client=HOLDER
    )
    assert other != key


def test_a_grant_without_a_key_agreement_key_is_refused() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    refusal = lease.acquire(HOLDER, "zid", False).refusal
    assert refusal is not None and "key-agreement key 'pub'" in refusal and lease.holder is None
    refusal = lease.acquire(HOLDER, "zid", False, pub=b"\0" * 32).refusal  # a low-order point
    assert refusal is not None and "not usable" in refusal and lease.holder is None


def test_a_holders_reset_is_signed_numbered_and_accepted_once() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    key = granted(lease, HOLDER)
    first = b'{"seq":1,"episode":2}'
    unsigned = lease.acquire(HOLDER, "zid", False, seq=1, payload=first).refusal
    assert unsigned is not None and "does not prove" in unsigned
    proof = request_proof(key, "reset", first)
    admission = lease.acquire(HOLDER, "zid", False, seq=1, proof=proof, payload=first)
    assert admission.refusal is None and not admission.repeat and not admission.node_pub
    assert lease.key == key  # a held reset keeps the key, and no key-agreement reply


def test_a_replayed_or_altered_reset_of_the_holder_is_refused_and_a_repeat_does_nothing() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    key = granted(lease, HOLDER, b"grant")
    first, second = b'{"seq":1}', b'{"seq":2}'
    admit = lease.acquire(
        HOLDER, "zid", False, seq=1, proof=request_proof(key, "reset", first), payload=first
    )
    assert admit.refusal is None and not admit.repeat
    again = lease.acquire(
        HOLDER, "zid", False, seq=1, proof=request_proof(key, "reset", first), payload=first
    )
    assert again.refusal is None and again.repeat  # the same request arriving twice: served once
    altered = b'{"seq":1,"x":1}'
    forged = lease.acquire(
        HOLDER, "zid", False, seq=1, proof=request_proof(key, "reset", first), payload=altered
    )
    assert forged.refusal is not None and "signature is wrong" in forged.refusal
    ok = lease.acquire(HOLDER, "zid", False, seq=2, proof=request_proof(key, "reset", second), payload=second)
    assert ok.refusal is None and not ok.repeat
    old = lease.acquire(HOLDER, "zid", False, seq=1, proof=request_proof(key, "reset", first), payload=first)
    assert old.refusal is not None and "used already" in old.refusal
    # the grant replayed after the lease has moved on: refused, and no key in sight
    grant = lease.acquire(HOLDER, "zid", False, pub=lease.holder.client_pub, payload=b"grant")  # type: ignore[union-attr]
    assert grant.refusal is not None and lease.key == key


def test_a_state_request_is_the_holders_alone_and_single_use() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    lease.token(OTHER, alive=True)
    key = granted(lease, HOLDER)
    payload = b"state-1"
    assert lease.admit_request(HOLDER, 1, request_proof(key, "state", payload), payload, "state") is None
    replay = lease.admit_request(HOLDER, 1, request_proof(key, "state", payload), payload, "state")
    assert replay is not None and "used already" in replay
    other = lease.admit_request(OTHER, 2, request_proof(key, "state", payload), payload, "state")
    assert other is not None and "only the holder" in other
    assert lease.admit_request(0, 2, b"", payload, "state") is not None
    assert reply_proof(key, payload, "") != reply_proof(key, payload, "ab")  # the state is covered


def test_a_take_over_gets_a_new_key_and_the_former_holder_is_told_with_its_own() -> None:
    lease = Lease("n")
    lease.token(HOLDER, alive=True)
    key = granted(lease, HOLDER)
    lease.token(OTHER, alive=True)
    assert lease.acquire(OTHER, "z2", False, pub=KeyPair().public).refusal is not None  # held
    assert granted(lease, OTHER, take_over=True) == lease.key != key
    old = proto.encode_values(proto.ACTION, 1, 1, HOLDER, [0.0], key=key)
    assert lease.former_key(HOLDER, old) == key  # the taken-over holder's reject is signed for it
    assert lease.former_key(HOLDER, proto.encode_values(proto.ACTION, 1, 1, HOLDER, [0.0])) is None
    assert lease.acquire(0, "", False).refusal is not None  # anonymous: never while held
