"""A node's request/reply side: the reset and info queries, and what ``info`` says.

Every request is checked before use (``bridge.net.requests``): a reset may set only what the
node serves (``bridge.net.served``), input values must be finite and inside their range,
payloads have a size limit; anything else gets an error reply ``<code>: <what was wrong>``,
and error texts carry no local paths. A reset from another client than the lease's holder is
refused unless it takes the node over (``bridge.net.lease``).
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bridge.errors import BridgeError, StepError
from bridge.fmu.vocab import summary_of
from bridge.net import node_start
from bridge.net import protocol as proto
from bridge.net.handshake import reply_proof
from bridge.net.requests import BadRequest, Refused, check_empty, parse_reset, redact

if TYPE_CHECKING:
    from bridge.net.node import FmuNode

_log = logging.getLogger(__name__)


def answer_reset(node: FmuNode, query: Any) -> None:
    """Reply to a reset query: the step-0 OUTPUTS frame, or an error reply saying why not."""
    try:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        reply, attachment = checked_reset(node, payload, attached(query))
    except BadRequest as exc:
        return _reply_err(node, query, "bad_request", str(exc))
    except Refused as exc:
        return _reply_err(node, query, exc.code, str(exc))
    except StepError as exc:  # the model failed at the reset: its words, for the client's same error
        return _reply_err(node, query, MODEL_FAILED_CODE, model_failure(exc))
    except BridgeError as exc:
        return _reply_err(node, query, "failed", f"reset failed: {exc}")
    except Exception as exc:  # never let a handler die: count it, log it, answer
        _log.exception("node %s: a reset could not be handled", node.name)
        return _reply_err(
            node, query, "internal", f"the node could not handle the reset ({type(exc).__name__})"
        )
    # the node's half of the key agreement and the reply's proof travel beside the step-0 frame
    query.reply(node.keys.reset, reply, attachment=attachment)
    return None


def attached(query: Any, limit: int = 64) -> bytes:
    """A query's attachment (a holder's request signature); longer than ``limit``: none."""
    attachment = query.attachment
    data = attachment.to_bytes() if attachment is not None else b""
    return data if len(data) <= limit else b""


MODEL_FAILED_CODE = "model_failed"


def model_failure(exc: StepError) -> str:
    """A reset's StepError as the ``model_failed`` reply carries it (JSON; read back by
    ``bridge.net.client``): what failed, the cause, the hint, the FMU's log and the time."""
    words: dict[str, Any] = {"what": exc.what, "detail": exc.detail, "hint": exc.hint}
    words.update(log=exc.log[-20:], time_s=exc.time_s)
    return json.dumps(words, ensure_ascii=False)


def checked_reset(node: FmuNode, payload: bytes, proof: bytes = b"") -> tuple[bytes, bytes | None]:
    """Parse and check a reset request, take or keep the lease, reset; the step-0 frame and the
    reply's attachment (None for an anonymous reset): JSON with the node's key-agreement key
    ``pub`` (when the reset starts a lease), the checksum of the sent ``state`` its episodes start
    from ("" for none) and ``proof``, both bound to this request under the session key."""
    request = parse_reset(payload)
    node.check_active()  # before the lease: a refused reset takes nothing
    values = node.rules.values(request.values)
    if request.inputs is not None:
        n = len(node.input_names)
        if len(request.inputs) != n:
            raise BadRequest(
                f"reset request: {len(request.inputs)} inputs, expected {n} ({list(node.input_names)})"
            )
        reason = node.rules.inputs(request.inputs)
        if reason is not None:
            raise BadRequest(f"reset request: {reason}")
    admission = node.lease.acquire(
        request.client, request.zid, request.take_over,
        pub=request.pub, seq=request.seq, proof=proof, payload=payload,
    )  # fmt: skip
    if admission.refusal is not None:
        raise Refused("busy", admission.refusal)
    if admission.repeat:
        frame = _served_again(node, request.episode)
    else:
        if admission.node_pub:  # a new lease: a state sent in the last one ends with it
            node_start.end_with_lease(node)
        frame = node.reset(values, request.inputs, request.episode)
    key = node.lease.key
    if not request.client or key is None:
        return frame, None
    state = node_start.active_state(node)
    words = {"pub": admission.node_pub.hex(), "state": state, "proof": reply_proof(key, payload, state).hex()}
    return frame, proto.encode_json(words)


def _served_again(node: FmuNode, episode: int) -> bytes:
    """The step-0 frame of the holder's last reset, asked again before anything else happened."""
    state = node.lockstep
    if (state.episode, state.step) != (episode, 0) or not state.last_frame:
        raise Refused(
            "busy",
            f"node {node.name!r}: this reset was served already and its episode has moved on "
            f"(episode {state.episode}, step {state.step}): a replayed request",
        )
    node.counters["resets_repeated"] += 1
    return state.last_frame


def _reply_err(node: FmuNode, query: Any, code: str, message: str) -> None:
    node.counters[f"reset_{code}"] += 1
    query.reply_err(f"{code}: {redact(message)}".encode())


def answer_info(node: FmuNode, query: Any) -> None:
    try:
        check_empty(query.payload.to_bytes() if query.payload is not None else None, "an info request")
        query.reply(node.keys.info, proto.encode_json(describe(node)))
    except BadRequest as exc:
        node.counters["info_bad_request"] += 1
        query.reply_err(f"bad_request: {exc}".encode())
    except Exception as exc:
        _log.exception("node %s: an info request could not be handled", node.name)
        query.reply_err(f"internal: the node could not describe itself ({type(exc).__name__})".encode())


def describe(node: FmuNode) -> dict[str, Any]:
    """What ``fmu-bridge nodes`` and remote envs learn about ``node`` (its ``info`` reply)."""
    t, state, served = node.timing, node.lockstep, node.served
    health, health_detail = node.health.report(node.plant.unusable)
    busy = node.watchdog.busy()  # a client whose reset outlasts its deadline asks whether it runs
    return {
        "node": node.name,
        "zid": node.zid,
        "mode": node.mode,
        "rate": node.rate,
        "pid": os.getpid(),
        "experiment": served.title,
        "version": served.version,
        "fmu_sha256": node.checksum,
        "step_size_s": t.step_size_s,
        "steps_per_sample": t.steps_per_sample,
        "sampling_time_s": t.sampling_time_s,
        "start_time_s": t.start_time_s,
        "input_names": list(node.input_names),
        "output_names": list(node.output_names),
        "input_range": [list(pair) for pair in zip(node.rules.low, node.rules.high)],
        "episode": state.episode,
        "step": state.step,
        "time_s": node.plant.time_s,
        "health": health,
        "health_detail": health_detail,
        "active": not node.lockstep.inactive,  # False: a managed node that steps for nobody now
        "holder": node.lease.describe(),
        "start_state": node_start.active_state(node),
        "isolated": node.isolated,
        "can_save_state": node.saved.available,
        "save_state_refusal": node.saved.refusal or "",
        "step_timeout_s": node.step_timeout_s,
        "busy": None if busy is None else {"call": busy[0], "for_s": round(busy[1], 3)},
        "counters": dict(node.counters),
        "model": _summary_without_paths(summary_of(node.info)),
    }


def _summary_without_paths(summary: dict[str, Any]) -> dict[str, Any]:
    """The model summary for the network: the FMU's file name, not where it lives on this machine."""
    if "path" in summary:
        summary = {**summary, "path": Path(str(summary["path"])).name}
    return summary
