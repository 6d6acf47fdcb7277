"""The lockstep rules of a node as plain unit tests: no Zenoh, no subprocess, no sleep."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import pytest

from bridge.net import lockstep as ls
from bridge.net import protocol as proto
from bridge.net.lease import Lease

HOLDER, OTHER = 0x1111, 0x2222
STATE_OK = None


def in_range(values: Sequence[float]) -> str | None:
    return None if all(-1.0 <= v <= 1.0 for v in values) else f"{list(values)} is outside [-1, 1]"


def started(episode: int = 3) -> ls.Lockstep:
    """Episode ``episode`` held by HOLDER, stepped once (step 1 done, step 2 next)."""
    lease = Lease("n")
    assert lease.acquire(HOLDER, "zid", False) is None
    state = ls.Lockstep(lease, in_range)
    state.started(episode, b"step-0")
    state.stepped((HOLDER, b"a1"), [0.0], 1_000, terminated=False)
    return state


def verdict(
    state: ls.Lockstep,
    episode: int,
    step: int,
    *,
    client: int = HOLDER,
    values: Sequence[float] = (0.5,),
    flags: int = 0,
    action: bytes = b"a2",
    refusal: str | None = STATE_OK,
) -> ls.Step | ls.Reject:
    refused = state.admit(client, values, flags, refusal)
    if refused is not None:
        return refused
    return state.order(episode, step, flags, (client, action))


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
            {"episode": 3, "step": 1, "action": b"other"},
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
    assert not state.plain(3, 2, HOLDER, [0.5])


def test_a_duplicate_of_the_last_step_is_a_retry_never_a_second_step() -> None:
    state = started()
    assert verdict(state, 3, 1, action=b"a1") == ls.RETRY
    assert state.last_frame.startswith(proto.HEADER.pack(proto.VERSION, proto.OUTPUTS, 0, 3, 1, 1_000))
    assert state.step == 1


def test_the_next_step_advances_and_an_ended_episode_refuses_more() -> None:
    state = started()
    assert verdict(state, 3, 2) == ls.ADVANCE
    assert state.plain(3, 2, HOLDER, [0.5])
    frame = state.stepped((HOLDER, b"a2"), [0.25], 2_000, terminated=True)
    decoded = proto.decode(frame)
    assert (decoded.episode, decoded.step, decoded.terminated, decoded.floats) == (3, 2, True, (0.25,))
    assert reason(verdict(state, 3, 3)) == ls.ENDED
    assert not state.plain(3, 3, HOLDER, [0.5])
    state.started(4, b"step-0")
    assert verdict(state, 4, 1) == ls.ADVANCE


def test_a_failed_step_ends_the_episode_and_its_retry_gets_the_error_again() -> None:
    state = started()
    frame = state.failed((HOLDER, b"a2"), "the model failed", 1_000, hung=True)
    decoded = proto.decode(frame)
    assert decoded.kind == proto.ERROR and decoded.flags == proto.FAILED | proto.HUNG
    assert (decoded.step, decoded.sim_time_ns) == (2, 1_000)  # the time the step started at, not 0
    assert verdict(state, 3, 2, action=b"a2") == ls.RETRY and state.last_frame == frame
    assert reason(verdict(state, 3, 3)) == ls.ENDED


def test_a_restore_makes_the_step_it_names_the_next_one_again() -> None:
    state = started()
    state.stepped((HOLDER, b"a2"), [0.0], 2_000, terminated=False)  # steps 1, 2 done
    order = verdict(state, 3, 2, flags=proto.RESTORE_STATE)
    assert order == ls.Step(restore=True)
    state.restored(2)
    assert state.next(2, 0) == ls.ADVANCE and (state.step, state.last_frame) == (1, b"")
    save = verdict(state, 3, 2, flags=proto.SAVE_STATE)
    assert save == ls.Step(save=True)


def test_the_fast_path_accepts_exactly_the_plain_next_step() -> None:
    state = started()
    assert state.plain(3, 2, HOLDER, [0.5])
    for episode, step, client, values in [
        (2, 2, HOLDER, [0.5]),
        (3, 3, HOLDER, [0.5]),
        (3, 1, HOLDER, [0.5]),
        (3, 2, OTHER, [0.5]),
        (3, 2, -1, [0.5]),
        (3, 2, HOLDER, [2.0]),
    ]:
        assert not state.plain(episode, step, client, values), (episode, step, client, values)
        sender = client if client >= 0 else OTHER
        assert verdict(state, episode, step, client=sender, values=values) != ls.ADVANCE


def test_nobody_holds_a_fresh_node_so_anyone_may_step_it_and_the_reject_frame_names_its_client() -> None:
    state = ls.Lockstep(Lease("n"), in_range)
    state.started(1, b"")
    assert verdict(state, 1, 1, client=0) == ls.ADVANCE
    frame = proto.decode(ls.Reject(ls.STALE, "old").frame(7, 8, OTHER))
    assert (frame.kind, frame.episode, frame.step, frame.sim_time_ns) == (proto.REJECT, 7, 8, OTHER)
    assert frame.message == "stale: old"
