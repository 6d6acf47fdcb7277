"""Replay a recording in Rerun: a ``.rrd`` file (``save``) or a spawned viewer.

The only module that imports ``rerun`` (the ``viz`` extra). The Rerun recording holds:

- one time series per signal, grouped by stream (``/observations/*``, ``/outputs/*``,
  ``/actions/*`` in physical units, ``/agent_action/*`` in [-1, 1] on a plot of its own,
  ``/reward``), in fixed colours, labelled with the FMU's units where the FMU can be read; a system
  of FMUs also gets one plot per component (``/components/NAME/outputs/*``);
- one plot per tracked output with its reference (``/tracking/<output>/...``; the reference
  rebuilt from the episode's scenario), the output in the agent's colour;
- a clear at every episode end, so no line joins two episodes;
- the scenario of each episode (name, seed, drawn values) as a Markdown document at the
  episode's start, the run's metadata as a static document, and episode starts and ends
  as text log entries;
- the cart-pole drawn in 2D when the outputs include ``x`` and ``theta``;
- timelines ``time`` (the recording clock: episodes back to back), ``sim_time`` and
  ``step`` (within the episode), and one ``episode_N`` timeline per episode (up to
  ``MAX_EPISODE_TIMELINES``): choosing it in the time panel shows only that episode (every
  plot, the scenario document and the episode log).

The viewer is started here, bound to 127.0.0.1 unless ``bind`` says otherwise; without a display
(no ``DISPLAY``/``WAYLAND_DISPLAY``) replay fails before building anything and suggests ``--save``.

Rerun reads the MCAP file itself too (``rerun file.mcap``); this adds the structure.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from bridge.errors import BridgeError, DependencyMissing
from bridge.recording import meta
from bridge.recording import replay_signals as sig
from bridge.recording.export import episode_of, steps_of
from bridge.recording.reader import Recording, read_recording

_log = logging.getLogger(__name__)
MAX_EPISODE_TIMELINES = 100
GROUPS = (meta.OBSERVATIONS, meta.OUTPUTS, meta.ACTIONS, meta.AGENT_ACTION, meta.REWARD)
PALETTE = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (188, 189, 34),
    (23, 190, 207),
]
CART_RGB, POLE_RGB, TRACK_RGB = (40, 70, 160), (220, 90, 30), (128, 128, 128)


def _rerun() -> Any:
    try:
        import rerun
    except ImportError as exc:
        raise DependencyMissing("rerun-sdk", "replay in Rerun", 'pip install "fmu-bridge[viz]"') from exc
    return rerun


def series_colour(group: str, index: int) -> tuple[int, int, int]:
    """The colour of signal ``index`` of a stream (streams start at different palette places)."""
    shift = {meta.OBSERVATIONS: 0, meta.OUTPUTS: 3, meta.ACTIONS: 6, meta.AGENT_ACTION: 7, meta.REWARD: 2}
    return PALETTE[(shift.get(group, 0) + index) % len(PALETTE)]


def replay(
    path: str | Path,
    *,
    save: str | Path | None = None,
    episode: int | None = None,
    spawn: bool = True,
    bind: str = "127.0.0.1",
) -> Path | None:
    """Build a Rerun recording of ``path``; write it to ``save`` or show it in a spawned viewer.

    Args:
        path: the MCAP recording (``.mcap``, or ``.mcap.part`` up to its last chunk).
        save: write a ``.rrd`` file here instead of spawning the viewer.
        episode: replay only this episode (its number in the recording).
        bind: address the spawned viewer listens on (loopback by default).

    Returns the ``.rrd`` path when saved. Raises BridgeError when the viewer cannot be shown.
    """
    rr = _rerun()
    if save is None and spawn:
        _check_display()
    import rerun.blueprint as rrb

    recording = read_recording(path)
    known = [e.index for e in recording.episodes]
    if episode is not None and episode not in known:
        raise BridgeError(f"--episode {episode}: {recording.path} has episodes {known or 'none'}")
    stream = rr.RecordingStream("fmu_bridge", recording_id=f"{Path(path).name}:{episode}")
    blueprint = _blueprint(rrb, recording)
    if save is not None:
        target = Path(save)
        target.parent.mkdir(parents=True, exist_ok=True)
        stream.save(str(target), default_blueprint=blueprint)
    elif spawn:
        port = _start_viewer(bind)
        stream.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=blueprint)
    try:
        _log_recording(rr, stream, recording, episode)
        stream.flush()
    except RuntimeError as exc:  # the viewer went away while we were sending
        raise BridgeError(
            f"the Rerun viewer closed the connection ({exc}); use --save RUN.rrd instead"
        ) from exc
    stream.disconnect()  # writes the .rrd footer now, not whenever the stream is collected
    return Path(save) if save is not None else None


def _check_display() -> None:
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise BridgeError(
            "cannot open the Rerun viewer: neither DISPLAY nor WAYLAND_DISPLAY is set (no display here); "
            "write a file with --save RUN.rrd and open it where there is a display (rerun RUN.rrd)"
        )


def _start_viewer(bind: str) -> int:
    """Start ``rerun`` listening on ``bind`` at a free port; fail clearly when it does not come up."""
    binary = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if binary is None:
        raise BridgeError(
            'cannot start the Rerun viewer: no rerun executable (pip install "fmu-bridge[viz]"); '
            "use --save RUN.rrd instead"
        )
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    process = subprocess.Popen(
        [binary, "--bind", bind, "--port", str(port)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline:
        if process.poll() is not None:
            error = (process.stderr.read() if process.stderr else b"").decode(errors="replace").strip()
            raise BridgeError(
                f"the Rerun viewer exited at start (code {process.returncode}): {error[-400:]}; "
                "use --save RUN.rrd instead"
            )
        with socket.socket() as client:
            if client.connect_ex(("127.0.0.1", port)) == 0:
                return port
        time.sleep(0.1)
    raise BridgeError(
        f"the Rerun viewer did not listen on port {port} within 20 s; use --save RUN.rrd instead"
    )


def _blueprint(rrb: Any, recording: Recording) -> Any:
    tracked = [out for out, _ in sig.tracking_pairs(sig.config(recording))]
    plots = [
        rrb.TimeSeriesView(origin=f"/tracking/{out}", name=f"{out}: reference and output") for out in tracked
    ]
    plots += [
        rrb.TimeSeriesView(origin=meta.OUTPUTS, name="outputs (unscaled)"),
        rrb.TimeSeriesView(origin=meta.ACTIONS, name="FMU inputs (physical units)"),
        rrb.TimeSeriesView(origin=meta.AGENT_ACTION, name="agent action (-1..1)"),
        rrb.TimeSeriesView(origin=meta.OBSERVATIONS, name="observations (scaled)"),
        rrb.TimeSeriesView(origin=meta.REWARD, name="reward"),
        *_component_views(rrb, recording),
        *_agent_views(rrb, recording),
    ]
    top = [
        rrb.TextDocumentView(origin="/scenario", name="scenario"),
        rrb.TextLogView(origin="/events", name="episodes"),
    ]
    if _cartpole_columns(recording) is not None:
        bounds = rrb.VisualBounds2D(x_range=[-2.8, 2.8], y_range=[-1.4, 0.4])
        top.insert(0, rrb.Spatial2DView(origin="/cartpole", name="cart-pole", visual_bounds=bounds))
    return rrb.Blueprint(
        rrb.Vertical(rrb.Grid(*plots, grid_columns=2), rrb.Horizontal(*top), row_shares=[3, 2]),
        # paused: a viewer that follows the newest data shows nothing until the whole file is in
        rrb.TimePanel(state="collapsed", timeline="time", play_state="paused"),
        collapse_panels=True,
    )


def component_topics(recording: Recording) -> list[str]:
    """The per-component output topics of a recorded system of FMUs, in recording order."""
    return [t for t in recording.series if t.startswith(meta.COMPONENTS) and t.endswith("/outputs")]


def _component_views(rrb: Any, recording: Recording) -> list[Any]:
    """One plot per component of a system of FMUs: its outputs under ``/components/NAME/outputs``."""
    views = []
    for topic in component_topics(recording):
        name = topic.removeprefix(meta.COMPONENTS).removesuffix("/outputs")
        views.append(rrb.TimeSeriesView(origin=topic, name=f"component {name}"))
    return views


def agent_topics(recording: Recording) -> list[str]:
    """The per-agent topics of a recording of several agents in one system (``/agents/NAME/...``)."""
    return [t for t in recording.series if t.startswith(meta.AGENTS)]


def _agent_views(rrb: Any, recording: Recording) -> list[Any]:
    """One plot per agent: its observations, FMU inputs, raw action and reward."""
    agents = dict.fromkeys(t.removeprefix(meta.AGENTS).rsplit("/", 1)[0] for t in agent_topics(recording))
    return [rrb.TimeSeriesView(origin=f"{meta.AGENTS}{name}", name=f"agent {name}") for name in agents]


def _log_recording(rr: Any, stream: Any, recording: Recording, episode: int | None) -> None:
    stream.log("/about", rr.TextDocument(_about(recording), media_type=rr.MediaType.MARKDOWN), static=True)
    unit_of = sig.units(recording)
    for group in (*GROUPS, *component_topics(recording), *agent_topics(recording)):
        series = recording.series.get(group)
        if series is None or not len(series):
            continue
        names = series.names if series.values.ndim == 2 else ["reward"]
        values = series.values if series.values.ndim == 2 else series.values[:, None]
        rows = _rows(recording, series, episode)
        kind = "/" + group.rsplit("/", 1)[-1] if group.startswith(meta.AGENTS) else group  # an agent's stream
        for i, name in enumerate(names):
            entity = f"{group}/{name}" if series.values.ndim == 2 else group
            text = sig.label(kind, name, unit_of)
            if kind != group:
                text = f"{group.removeprefix(meta.AGENTS).rsplit('/', 1)[0]}: {text}"
            style = rr.SeriesLines(colors=[series_colour(kind, i)], names=text, widths=2.0)
            stream.log(entity, style, static=True)
            _send(rr, stream, entity, rows, lambda r, i=i, v=values: rr.Scalars.columns(scalars=v[r, i]))
    _log_tracking(rr, stream, recording, episode, unit_of)
    _log_episodes(rr, stream, recording, episode)
    _log_cartpole(rr, stream, recording, episode)


def _log_tracking(
    rr: Any, stream: Any, recording: Recording, episode: int | None, unit_of: dict[str, str]
) -> None:
    """Reference and output of each tracked signal on one plot; the output in the agent's colour."""
    outputs = recording.series.get(meta.OUTPUTS)
    cfg = sig.config(recording)
    if outputs is None or not len(outputs):
        return
    agent = str(recording.metadata.get("fmu_bridge", {}).get("agent") or "agent")
    rows = _rows(recording, outputs, episode)
    sim_s = outputs.stamp_ns.astype(np.float64) / 1e9
    for out, ref in sig.tracking_pairs(cfg):
        if out not in outputs.names:
            continue
        unit = f" [{unit_of[out]}]" if out in unit_of else ""
        column = outputs.values[:, outputs.names.index(out)]
        entity = f"/tracking/{out}/output"
        stream.log(entity, rr.SeriesLines(colors=[sig.agent_colour(agent)], names=f"{out}{unit} ({agent})",
                                          widths=2.0), static=True)  # fmt: skip
        _send(rr, stream, entity, rows, lambda m, c=column: rr.Scalars.columns(scalars=c[m]))
        reference = sig.reference_values(cfg, recording, ref, rows["episode"], sim_s)
        if reference is None:
            continue
        entity = f"/tracking/{out}/reference"
        name = f"{ref}{unit} (reference)"
        style = rr.SeriesLines(colors=[sig.VIEWER_REFERENCE_RGB], names=name, widths=1.5)
        stream.log(entity, style, static=True)
        _send(rr, stream, entity, rows, lambda m, c=reference: rr.Scalars.columns(scalars=c[m]))


def _rows(recording: Recording, series: Any, episode: int | None) -> dict[str, Any]:
    """Row selection and time columns of a stream, split by episode for the episode timelines."""
    episodes = episode_of(recording, series.log_ns)
    keep = np.ones(len(series), dtype=bool) if episode is None else episodes == episode
    starts = {e.index: e.start_ns for e in recording.episodes}
    since_start = series.log_ns - np.array([starts.get(int(e), 0) for e in episodes], dtype=np.int64)
    return {
        "keep": keep,
        "episode": episodes,
        "time": series.log_ns.astype("timedelta64[ns]"),  # exact: no float seconds in between
        "sim_time": series.stamp_ns.astype("timedelta64[ns]") if series.stamped else None,
        # unstamped streams (reward): the time since the episode's start on the recording clock
        "in_episode": (series.stamp_ns if series.stamped else since_start).astype("timedelta64[ns]"),
        "step": steps_of(recording, series),
        "per_episode": len(recording.episodes) <= MAX_EPISODE_TIMELINES,
    }


def _send(rr: Any, stream: Any, entity: str, rows: dict[str, Any], columns: Any) -> None:
    """``send_columns`` once per episode (each with its own episode timeline), then a clear, so
    that no line joins the last sample of an episode to the first of the next."""
    for number in np.unique(rows["episode"][rows["keep"]]):
        mask = rows["keep"] & (rows["episode"] == number)
        indexes = [
            rr.TimeColumn("time", duration=rows["time"][mask]),
            rr.TimeColumn("step", sequence=rows["step"][mask]),
        ]
        if rows["sim_time"] is not None:
            indexes.append(rr.TimeColumn("sim_time", duration=rows["sim_time"][mask]))
        if rows["per_episode"] and number >= 0:
            indexes.append(rr.TimeColumn(f"episode_{number}", duration=rows["in_episode"][mask]))
        stream.send_columns(entity, indexes=indexes, columns=columns(mask))
        stream.set_time("time", duration=rows["time"][mask][-1] + np.timedelta64(1, "ns"))
        stream.log(entity, rr.Clear(recursive=False))
        stream.reset_time()


def _log_episodes(rr: Any, stream: Any, recording: Recording, only: int | None) -> None:
    per_episode = len(recording.episodes) <= MAX_EPISODE_TIMELINES
    for ep in recording.episodes:
        if only is not None and ep.index != only:
            continue
        _episode_time(stream, ep.index, ep.start_ns, 0, per_episode)
        lines = [f"## Episode {ep.index}", f"- scenario: `{ep.scenario}`", f"- seed: {ep.seed}"]
        lines += [f"- {name} = {value:.6g}" for name, value in ep.drawn.items()]
        stream.log("/scenario", rr.TextDocument("\n".join(lines), media_type=rr.MediaType.MARKDOWN))
        text = f"episode {ep.index} starts: scenario {ep.scenario}, seed {ep.seed}"
        stream.log("/events", rr.TextLog(text, level="INFO"))
        if ep.end_ns is not None:
            _episode_time(stream, ep.index, ep.end_ns, ep.end_ns - ep.start_ns, per_episode)
            text = f"episode {ep.index} ends after {ep.steps} steps: return {ep.episode_return}, {ep.reason}"
            stream.log(
                "/events", rr.TextLog(text, level="WARN" if ep.reason not in (None, "time") else "INFO")
            )
        stream.reset_time()


def _episode_time(stream: Any, index: int, log_ns: int, since_start_ns: int, per_episode: bool) -> None:
    stream.reset_time()
    stream.set_time("time", duration=np.timedelta64(log_ns, "ns"))
    if per_episode:
        stream.set_time(f"episode_{index}", duration=np.timedelta64(since_start_ns, "ns"))


def _about(recording: Recording) -> str:
    run = recording.metadata.get("fmu_bridge", {})
    lines = [f"# {run.get('experiment', recording.path.name)}", f"- file: `{recording.path}`"]
    for key in ("version", "agent", "env", "node", "fmu_sha256", "sampling_time_s"):
        if run.get(key):
            lines.append(f"- {key}: `{run[key]}`")
    if not recording.complete:
        lines.append("- **unfinished recording**: read up to its last complete chunk")
    return "\n".join(lines)


def _cartpole_columns(recording: Recording) -> tuple[int, int] | None:
    outputs = recording.series.get(meta.OUTPUTS)
    if outputs is None or "x" not in outputs.names or "theta" not in outputs.names:
        return None
    return outputs.names.index("x"), outputs.names.index("theta")


def _pole_lengths_m(recording: Recording, log_ns: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """The drawn pole per row: twice the model's ``length`` (pivot to centre of mass), from the
    episode's drawn values, else the experiment's parameters, else 0.5 m."""
    config = recording.metadata.get("fmu_bridge", {}).get("config")
    try:
        parameters = (yaml.safe_load(config) or {}).get("model", {}).get("parameters", {}) if config else {}
        nominal = float(parameters.get("length", 0.5))
    except (yaml.YAMLError, TypeError, ValueError, AttributeError):
        nominal = 0.5
    per_episode = {e.index: float(e.drawn.get("length", nominal)) for e in recording.episodes}
    episodes = episode_of(recording, log_ns)
    return 2.0 * np.array([per_episode.get(int(e), nominal) for e in episodes], dtype=np.float64)


def _log_cartpole(rr: Any, stream: Any, recording: Recording, episode: int | None) -> None:
    found = _cartpole_columns(recording)
    if found is None:
        return
    outputs = recording.series[meta.OUTPUTS]
    x, theta = outputs.values[:, found[0]], outputs.values[:, found[1]]
    cart_w, cart_h, pole = 0.4, 0.2, _pole_lengths_m(recording, outputs.log_ns)
    stream.log(
        "/cartpole/track",
        rr.LineStrips2D([[[-2.4, 0.0], [2.4, 0.0]]], colors=[TRACK_RGB], radii=0.01),
        static=True,
    )
    # Static parts only for what never changes: static data would hide the logged positions.
    cart = rr.Boxes2D.from_fields(half_sizes=[[cart_w / 2, cart_h / 2]], colors=[CART_RGB])
    stream.log("/cartpole/cart", cart, static=True)
    stream.log("/cartpole/pole", rr.LineStrips2D.from_fields(colors=[POLE_RGB], radii=0.025), static=True)
    rows = _rows(recording, outputs, episode)
    # The 2D view's y axis points down: heights are negative.
    tip_x, tip_y = x + pole * np.sin(theta), -(cart_h + pole * np.cos(theta))
    strips = np.stack(
        [np.column_stack([x, np.full_like(x, -cart_h)]), np.column_stack([tip_x, tip_y])], axis=1
    )
    centres = np.column_stack([x, np.full_like(x, -cart_h / 2)])
    _send(rr, stream, "/cartpole/cart", rows, lambda m: rr.Boxes2D.columns(centers=centres[m]))
    _send(rr, stream, "/cartpole/pole", rows, lambda m: rr.LineStrips2D.columns(strips=strips[m]))
