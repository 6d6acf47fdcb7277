"""Recording commands for the ``fmu-bridge`` app: record, replay, info, export, recover.

Thin shims: each parses its options and calls a typed function of ``bridge.recording``
(``node_recorder``, ``replay``, ``playback``, ``export`` or ``reader``).
"""

from __future__ import annotations

import json
import signal
import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from bridge.cli.options import (
    ConnectOpt,
    ListenOpt,
    PrefixOpt,
    ZenohConfigOpt,
    ZenohModeOpt,
    console,
    err_console,
)
from bridge.cli.options import zenoh_options as _zenoh_options
from bridge.errors import BridgeError

RecordingArg = Annotated[Path, typer.Argument(help="An MCAP recording (.mcap, or an unfinished .mcap.part).")]


def record(
    *,
    node: Annotated[str, typer.Option("--node", help="Name of the node to record.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="The MCAP file to write.")],
    topics: Annotated[
        str, typer.Option("--topics", help="Comma-separated: outputs, actions.")
    ] = "outputs,actions",
    duration_s: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds (wall clock).")
    ] = None,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
    timeout_s: Annotated[float, typer.Option("--timeout", help="Seconds to wait for the node.")] = 5.0,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing file.")] = False,
) -> None:
    """Record a running node's topics into an MCAP file (like ros2 bag record) until Ctrl-C."""
    from bridge.net.transport import open_session
    from bridge.recording.node_recorder import NodeRecorder

    session = open_session(_zenoh_options(zenoh_config, listen, connect, zenoh_mode=zenoh_mode))
    try:
        chosen = tuple(t.strip() for t in topics.split(",") if t.strip())
        recorder = NodeRecorder(
            session, node, output, prefix=prefix, topics=chosen, timeout_s=timeout_s, overwrite=force
        )
        # SIGTERM as Ctrl-C (a KeyboardInterrupt in the main thread, handled below): a handler that
        # takes a lock the interrupted main thread may hold could deadlock
        signal.signal(signal.SIGTERM, signal.default_int_handler)
        err_console.print(
            f"recording {', '.join(chosen)} of node {node!r} into {output}; Ctrl-C stops", highlight=False
        )
        try:
            stats = recorder.run(duration_s)
        except KeyboardInterrupt:
            stats = recorder.stats
        finally:
            path = recorder.close()
    finally:
        session.close()
    frames = ", ".join(f"{n} {t}" for t, n in stats.frames.items()) or "no frames"
    console.print(
        f"wrote {path}: {frames}, {stats.episodes} episode(s), "
        f"{stats.malformed} malformed and {stats.unplaced} unplaceable frame(s) skipped, "
        f"{stats.repeated} repeated pass(es) of a step replaced by the last"
    )


def replay_cmd(
    recording: RecordingArg,
    *,
    save: Annotated[
        Path | None, typer.Option("--save", help="Write a .rrd file instead of opening the viewer.")
    ] = None,
    episode: Annotated[int | None, typer.Option("--episode", help="Only this episode.")] = None,
    bind: Annotated[
        str, typer.Option("--bind", help="Address the spawned viewer listens on (loopback by default).")
    ] = "127.0.0.1",
    publish: Annotated[
        bool, typer.Option("--publish", help="Play the outputs back over Zenoh as the node's frames.")
    ] = False,
    node: Annotated[str, typer.Option("--node", help="Node name to publish as (--publish).")] = "replay",
    rate: Annotated[
        float, typer.Option("--rate", help="Playback speed (--publish): 1 as recorded, 0 max.")
    ] = 1.0,
    zenoh_config: ZenohConfigOpt = None,
    listen: ListenOpt = None,
    connect: ConnectOpt = None,
    zenoh_mode: ZenohModeOpt = None,
    prefix: PrefixOpt = "fmu_bridge",
) -> None:
    """Replay a recording in Rerun (viewer, or --save FILE.rrd), or over Zenoh with --publish."""
    if not publish:
        from bridge.recording.replay import replay

        saved = replay(recording, save=save, episode=episode, bind=bind)
        console.print(
            f"wrote {saved}" if saved else f"sent {recording} to the Rerun viewer (listening on {bind})"
        )
        return
    from bridge.recording.playback import publish as play

    stop = threading.Event()
    # SIGTERM as Ctrl-C (a KeyboardInterrupt in the main thread, handled below): a handler that
    # takes a lock the interrupted main thread may hold could deadlock
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    err_console.print(f"publishing {recording} as node {prefix}/{node} at rate {rate:g}; Ctrl-C stops")
    options = _zenoh_options(zenoh_config, listen, connect, zenoh_mode=zenoh_mode)
    try:
        sent = play(
            recording, node=node, options=options, prefix=prefix, rate=rate, episode=episode, stop=stop
        )
    except KeyboardInterrupt:
        stop.set()
        return
    console.print(f"published {sent} frames")


def info(
    recording: RecordingArg,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Channels, message counts, duration, episodes and metadata of a recording."""
    from bridge.recording.export import describe
    from bridge.recording.reader import read_recording

    data = read_recording(recording)
    summary = describe(data)
    if as_json:
        sys.stdout.write(json.dumps(summary, indent=2, default=str) + "\n")
        return
    state = "complete" if summary["complete"] else "[yellow]unfinished: read up to its last chunk[/yellow]"
    console.print(f"[bold]{escape(summary['path'])}[/bold]  ({state})")
    console.print(
        f"profile {summary['profile']}, {escape(summary['library'])}, duration {summary['duration_s']:.6g} s "
        f"(recording clock {summary['start_ns'] / 1e9:g} .. {summary['end_ns'] / 1e9:g} s)"
    )
    channels = Table("topic", "type", "messages", "names", title="channels")
    for ch in summary["channels"]:
        channels.add_row(ch["topic"], ch["type"], str(ch["messages"]), escape(", ".join(ch["names"])))
    console.print(channels)
    _episodes_table(summary["episodes"])
    _metadata_table(summary["metadata"], summary["attachments"])
    _warn_skipped(data.problems, data.problem_count)


def _warn_skipped(problems: list[str], count: int) -> None:
    """What a damaged recording's reader had to skip, on stderr."""
    if not count:
        return
    err_console.print(
        f"[yellow]warning: {count} part(s) of the file could not be read and were skipped:[/yellow]"
    )
    for text in problems:
        err_console.print(f"  {escape(text)}", highlight=False)
    if count > len(problems):
        err_console.print(f"  ... and {count - len(problems)} more", highlight=False)


def _episodes_table(episodes: list[dict[str, Any]]) -> None:
    table = Table(
        "episode", "scenario", "seed", "steps", "return", "end", title=f"{len(episodes)} episode(s)"
    )
    for e in episodes:
        ret = e["episode_return"]
        table.add_row(
            str(e["index"]),
            str(e["scenario"] or ""),
            "" if e["seed"] is None else str(e["seed"]),
            "" if e["steps"] is None else str(e["steps"]),
            "" if ret is None else f"{ret:.6g}",
            str(e["reason"] or ("" if e["end_ns"] is not None else "(unfinished)")),
        )
    console.print(table)


def _metadata_table(metadata: dict[str, dict[str, str]], attachments: list[dict[str, Any]]) -> None:
    table = Table("record", "key", "value", title="metadata")
    for name, entries in metadata.items():
        for key, value in entries.items():
            shown = f"({len(value.splitlines())} lines)" if "\n" in value.strip() else value
            shown = shown if len(shown) <= 100 else shown[:99] + "…"
            table.add_row(name, key, escape(shown))
    for a in attachments:
        table.add_row("attachment", escape(a["name"]), f"{a['media_type']}, {a['bytes']} bytes")
    console.print(table)


def export(
    recording: RecordingArg,
    csv: Annotated[Path | None, typer.Option("--csv", help="Write one CSV file per stream here.")] = None,
    parquet: Annotated[
        Path | None, typer.Option("--parquet", help="Write one Parquet file per stream here.")
    ] = None,
) -> None:
    """Export every stream of a recording as tables (time columns first)."""
    from bridge.recording.export import export_csv, export_parquet
    from bridge.recording.reader import read_recording

    if csv is None and parquet is None:
        raise BridgeError("export: give --csv DIR and/or --parquet DIR")
    data = read_recording(recording)
    _warn_skipped(data.problems, data.problem_count)
    written = (export_csv(data, csv) if csv else []) + (export_parquet(data, parquet) if parquet else [])
    for path in written:
        console.print(f"wrote {path}")


def recover(
    part: Annotated[Path, typer.Argument(help="An unfinished recording (NAME.mcap.part).")],
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Default: NAME.mcap beside it.")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite the output.")] = False,
) -> None:
    """Rewrite everything readable in an unfinished recording into a valid MCAP file."""
    from bridge.recording.reader import recover_file

    result = recover_file(part, output, overwrite=force)
    _warn_skipped(result.problems, result.problem_count)
    console.print(f"wrote {result.path}: {result.messages} messages")


def register(app: typer.Typer) -> None:
    """Add the recording commands to ``app``."""
    app.command("record")(record)
    app.command("replay")(replay_cmd)
    app.command("info")(info)
    app.command("export")(export)
    app.command("recover")(recover)
