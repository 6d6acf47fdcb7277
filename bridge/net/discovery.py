"""What nodes there are and what they say about themselves: ``info`` replies, checked.

Every reply is checked before use (issue: a malformed reply used to be a KeyError deep in a
client): a client's view (:class:`NodeInfo`, :func:`query_info`) needs every field it uses and
the model summary it describes, and takes the reply only from the session the reply names
(two sessions answering as one node are refused); a listing's view (:class:`NodeListing`,
:func:`describe_nodes`) types every field ``fmu-bridge nodes`` shows and fills the missing ones.
"""

from __future__ import annotations

import fnmatch
import time
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bridge.errors import TransportError
from bridge.fmu.vocab import info_from_summary
from bridge.net import protocol as proto


class NodeInfo(BaseModel):
    """What a client needs from a node's ``info`` reply; anything else in it is kept as is."""

    model_config = ConfigDict(extra="allow")

    node: str
    zid: str = Field(default="", max_length=64)  # "": a publisher of recorded frames
    experiment: str = ""
    fmu_sha256: str = ""
    input_names: list[str] = Field(max_length=proto.MAX_SIGNALS)
    output_names: list[str] = Field(max_length=proto.MAX_SIGNALS)
    step_size_s: float = Field(gt=0)
    steps_per_sample: int = Field(ge=1)
    sampling_time_s: float = Field(gt=0)
    start_time_s: float
    can_save_state: bool = False
    save_state_refusal: str = ""
    model: dict[str, Any]


class _HolderEntry(BaseModel):
    model_config = ConfigDict(extra="allow")
    client: str
    zid: str = ""


class _ModelEntry(BaseModel):
    model_config = ConfigDict(extra="allow")
    model_name: str = "?"


class NodeListing(BaseModel):
    """A node's ``info`` as ``fmu-bridge nodes`` lists it: every field typed, the missing ones
    filled (a recording published with ``replay --publish`` answers with fewer)."""

    model_config = ConfigDict(extra="allow")

    node: str
    zid: str = Field(default="", max_length=64)
    mode: str = "?"
    experiment: str = ""
    version: str = ""
    health: str = "?"
    holder: _HolderEntry | None = None
    episode: int = 0
    step: int = -1
    time_s: float = 0.0
    pid: int = 0
    counters: dict[str, int] = {}
    model: _ModelEntry = _ModelEntry()
    input_names: list[str] = []
    output_names: list[str] = []


def listed_info(payload: bytes, node: str, replier: str | None) -> dict[str, Any]:
    """A node's ``info`` reply for a listing (:class:`NodeListing`); TransportError if malformed."""
    data = proto.decode_json(payload, f"the info reply of node {node!r}", limit=proto.MAX_INFO_BYTES)
    try:
        listing = NodeListing.model_validate(data)
    except ValidationError as exc:
        raise _malformed_info(node, exc) from None
    if listing.node != node or (replier is not None and listing.zid not in ("", replier)):
        raise TransportError(
            f"the info reply for node {node!r} names node {listing.node!r}: not the node asked for"
        )
    return listing.model_dump()


def _malformed_info(node: str, exc: Exception) -> TransportError:
    first = exc.errors()[0] if isinstance(exc, ValidationError) else {"msg": repr(exc)[:200], "loc": ()}
    where = ".".join(str(p) for p in first.get("loc", ()))
    return TransportError(
        f"node {node!r} sent an info reply that the protocol does not allow"
        f"{f' ({where})' if where else ''}: {first['msg']}; is it a node of another version?"
    )


def checked_info(payload: bytes, node: str, replier: str | None) -> dict[str, Any]:
    """A node's ``info`` reply, checked against :class:`NodeInfo` (and its model summary), from
    the session it names; a TransportError naming the node says what is wrong otherwise."""
    data = proto.decode_json(payload, f"the info reply of node {node!r}", limit=proto.MAX_INFO_BYTES)
    try:
        info = NodeInfo.model_validate(data)
        info_from_summary(info.model)
    except (ValidationError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise _malformed_info(node, exc) from None
    if info.node != node or (replier is not None and info.zid not in ("", replier)):
        raise TransportError(
            f"the info reply for node {node!r} names node {info.node!r} of session {info.zid}, "
            f"and came from session {replier}: not the node asked for"
        )
    return data


def query_target() -> Any:
    """Ask every queryable of a key, not the best one: an impostor cannot hide the node."""
    import zenoh

    return zenoh.QueryTarget.ALL


def every_reply() -> Any:
    """Keep every reply: Zenoh's default consolidation keeps one reply per key, so another
    session answering on the node's key could hide the node's own reply (it did, depending on
    which reply came last)."""
    import zenoh

    return zenoh.ConsolidationMode.NONE


def _impostor(name: str, sessions: set[str | None]) -> str:
    return (
        f"{len(sessions)} Zenoh sessions answer as node {name!r} ({sorted(map(str, sessions))}); "
        "a node's name must be its own: stop the impostor, or use another name"
    )


def replier(reply: Any) -> str | None:
    rid = getattr(reply, "replier_id", None)
    return str(rid.zid) if rid is not None else None


def query_info(session: Any, keys: proto.Keys, timeout_s: float) -> dict[str, Any]:
    """The node's ``info`` reply; TransportError if no node of that name answers in
    ``timeout_s``, if two sessions answer as that node, or if the reply is malformed."""
    # A query sent before routes exist finds no queryable and returns at once: retry until the
    # timeout, so a just-opened session or a node that is still starting is found.
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        answers = [
            (reply.ok.payload.to_bytes(), replier(reply))
            for reply in session.get(
                keys.info,
                target=query_target(),
                consolidation=every_reply(),
                timeout=max(0.05, min(remaining, 1.0)),
            )
            if reply.ok is not None
        ]
        sessions = {zid for _, zid in answers}
        if len(sessions) > 1:
            raise TransportError(_impostor(keys.node, sessions))
        if answers:
            return checked_info(answers[0][0], keys.node, answers[0][1])
        if remaining <= 0:
            break
        time.sleep(min(0.1, max(remaining, 0.0)))
    raise TransportError(
        f"no FMU node named {keys.node!r} answers on {keys.info} within {timeout_s:g} s; "
        f"start one with `fmu-bridge node EXPERIMENT --name {keys.node}` and check the Zenoh endpoints "
        "(`fmu-bridge nodes` lists the live ones)"
    )


def list_nodes(
    session: Any, *, prefix: str = proto.DEFAULT_PREFIX, pattern: str = "*", timeout_s: float = 2.0
) -> list[str]:
    """Names of the live nodes under ``prefix`` whose name matches the glob ``pattern``."""
    names = []
    for reply in session.liveliness().get(f"{prefix}/**/alive", timeout=timeout_s):
        if reply.ok is None:
            continue
        key = str(reply.ok.key_expr)
        name = key[len(prefix) + 1 : -len("/alive")]
        if fnmatch.fnmatchcase(name, pattern):
            names.append(name)
    return sorted(set(names))


def describe_nodes(
    session: Any, names: list[str], *, prefix: str = proto.DEFAULT_PREFIX, timeout_s: float = 2.0
) -> list[dict[str, Any]]:
    """Each node's info reply (nodes that do not answer in time are reported with an error)."""
    found = []
    for name in names:
        keys = proto.Keys(prefix, name)
        entry: dict[str, Any] = {"node": name, "error": f"no answer within {timeout_s:g} s"}
        answers = [
            (reply.ok.payload.to_bytes(), replier(reply))
            for reply in session.get(
                keys.info, target=query_target(), consolidation=every_reply(), timeout=timeout_s
            )
            if reply.ok is not None
        ]
        sessions = {zid for _, zid in answers}
        if len(sessions) > 1:  # an impostor is listed as one, not shown as the node
            entry["error"] = _impostor(name, sessions)
        elif answers:
            try:
                entry = listed_info(answers[0][0], name, answers[0][1])
            except TransportError as exc:
                entry = {"node": name, "error": str(exc)}
        found.append(entry)
    return found
