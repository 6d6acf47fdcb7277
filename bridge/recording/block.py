"""Blocks of step records: the messages of many env steps packed at once with numpy.

Every step writes the same messages (one per step topic), and all their bytes are constant
except the sequence number, the log/publish times, the header stamps and the values. So a
block of ``n`` steps is one step's record template repeated ``n`` times, with the varying
fields filled column by column through a numpy structured dtype that mirrors the record
layout. A recorder then pays per step only for keeping the step's values (well under a
microsecond); the packing costs about as much per step again, in bulk, once per block.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bridge.net.ros2 import cdr
from bridge.recording import records as rec

IndexEntries = list[tuple[int, npt.NDArray[np.uint64]]]  # channel, (n, 2) array of (log time, offset)
_NS = 1_000_000_000


@dataclass(frozen=True)
class FixedMessage:
    """One message of every step.

    Args:
        channel_id: the channel it is written on.
        slot: the time slot it is stamped with; a recorder uses slot 0 for the action (applied
            from t_k) and slot 1 for what the step produced (at t_k+1).
        layout: the JointState layout (values: an ``(n, len(names))`` array), or None for a
            ``std_msgs/msg/Float64`` (values: an ``(n,)`` array).
    """

    channel_id: int
    slot: int = 0
    layout: cdr.JointStateLayout | None = None


# The fields a message record has after its constant prefix, grouped as they lie side by side:
# sequence, log and publish time; then (a JointState) the header stamp. One assignment fills a group.
_HEAD = np.dtype([("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")])  # packed: 20 bytes
_STAMP = np.dtype([("sec", "<i4"), ("nsec", "<u4")])


class StepBlock:
    """Packs ``n`` steps' messages into contiguous MCAP message records."""

    def __init__(self, messages: list[FixedMessage]) -> None:
        self.messages = messages
        self.count = 0  # steps packed so far: the next sequence number
        template = bytearray()
        names: list[str] = []
        formats: list[object] = []
        offsets: list[int] = []

        def field(name: str, fmt: object, size: int) -> None:
            names.append(name)
            formats.append(fmt)
            offsets.append(len(template))
            template.extend(bytes(size))

        self.record_offsets = []
        self._fields = []  # per message: the names of its head, stamp and value fields ("": none)
        for i, message in enumerate(messages):
            js = message.layout
            self.record_offsets.append(len(template))
            template += rec.message_prefix(message.channel_id, js.size if js is not None else 12)
            field(f"head{i}", "V20", _HEAD.itemsize)
            template += cdr.ENCAPSULATION
            if js is None:
                field(f"val{i}", "<f8", 8)
                self._fields.append((f"head{i}", "", f"val{i}"))
                continue
            field(f"stamp{i}", "<u8", _STAMP.itemsize)
            template += js.head
            if js.names:
                field(f"val{i}", ("<f8", (len(js.names),)), 8 * len(js.names))
            template += js.tail
            self._fields.append((f"head{i}", f"stamp{i}", f"val{i}" if js.names else ""))
        self.template = bytes(template)
        self._template_row = np.frombuffer(self.template, dtype=np.uint8)
        self._slots = np.array([m.slot for m in messages], dtype=np.intp)
        self._offsets = np.array(self.record_offsets, dtype=np.uint64)[:, None]
        self.size = len(template)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size})

    def pack(
        self,
        times: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]],
        values: list[npt.NDArray[np.float64]],
    ) -> tuple[bytearray, IndexEntries, tuple[int, int]]:
        """Records of ``n`` steps, their index entries and their (earliest, latest) log time.

        Args:
            times: per slot, (log times, header stamps) in ns, each of length ``n``.
            values: per message, its values (``(n, k)`` for a JointState, ``(n,)`` for a Float64).

        Index offsets are relative to the start of the block.
        """
        block = bytearray(len(times[0][0]) * self.size)
        index, bounds = self.pack_into(block, 0, times, values)
        return block, index, bounds

    def pack_into(
        self,
        buffer: bytearray,
        offset: int,
        times: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]],
        values: list[npt.NDArray[np.float64]],
    ) -> tuple[IndexEntries, tuple[int, int]]:
        """:meth:`pack`, with the records written into ``buffer`` at ``offset`` (which must hold
        them): a writer packs straight into its chunk. Index offsets are relative to the start of
        ``buffer``."""
        n = len(times[0][0])
        sequence = np.arange(self.count, self.count + n, dtype=np.uint64) & 0xFFFFFFFF
        logs = np.stack([log for log, _ in times])  # (slot, step)
        head = np.empty(logs.shape, dtype=_HEAD)
        head["seq"] = sequence
        head["log"] = logs
        head["pub"] = logs
        heads = head.view("V20")
        sec, nsec = np.divmod(np.stack([stamp for _, stamp in times]), _NS)
        pair = np.empty(logs.shape, dtype=_STAMP)
        pair["sec"] = sec
        pair["nsec"] = nsec
        stamps = pair.view("<u8")
        records = np.frombuffer(buffer, dtype=self.dtype, count=n, offset=offset)
        try:
            records.view(np.uint8).reshape(n, self.size)[:] = self._template_row
            for i, message in enumerate(self.messages):
                head_field, stamp_field, value_field = self._fields[i]
                records[head_field] = heads[message.slot]
                if stamp_field:
                    records[stamp_field] = stamps[message.slot]
                if value_field:
                    records[value_field] = values[i]
        finally:
            del records  # a view of ``buffer``: released (also on an error), so it can grow again
        # Index entries of all messages at once: (message, step) -> (log time, record offset).
        entries = np.empty((len(self.messages), n, 2), dtype="<u8")
        entries[:, :, 0] = logs[self._slots]
        starts = np.arange(offset, offset + n * self.size, self.size, dtype=np.uint64)
        entries[:, :, 1] = starts + self._offsets
        index: IndexEntries = [(m.channel_id, entries[i]) for i, m in enumerate(self.messages)]
        self.count += n
        return index, (int(logs.min()), int(logs.max()))
