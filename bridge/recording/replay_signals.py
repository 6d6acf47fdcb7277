"""What a replay draws beyond the recorded streams: units, labels, tracking references, agent colours.

Kept apart from ``replay.py`` (the Rerun side) and free of Rerun, so the evaluation report
(``agents/report.py``) takes its agent colours from here too: one colour per agent in every
plot and in the replay.
"""

from __future__ import annotations

import zlib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from bridge.recording import meta
from bridge.recording.reader import Recording

#: Colours of the agents (RGB): fixed for the built-in baselines, the rest by a hash of the name.
AGENT_PALETTE = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (148, 103, 189),
    (255, 127, 14),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
]
FIXED_AGENTS = {"pid": (127, 127, 127), "zero": (188, 189, 34), "random": (160, 160, 200)}
REFERENCE_RGB = (0, 0, 0)  # reports: black, dashed, on white
#: The reference in the Rerun viewer, whose plots have a near-black background: near-white there.
VIEWER_REFERENCE_RGB = (235, 235, 235)


def agent_colour(name: str) -> tuple[int, int, int]:
    """The colour of agent ``name``: the same in every report plot and replay."""
    key = Path(name.rstrip("/")).name or name
    if key in FIXED_AGENTS:
        return FIXED_AGENTS[key]
    return AGENT_PALETTE[zlib.crc32(key.encode()) % len(AGENT_PALETTE)]


def agent_colours(names: Iterable[str]) -> dict[str, tuple[int, int, int]]:
    """Colours of several agents, distinct while the palette lasts (hash collisions move on)."""
    out: dict[str, tuple[int, int, int]] = {}
    for name in names:
        colour = agent_colour(name)
        free = [c for c in AGENT_PALETTE if c not in out.values()]
        if colour in out.values() and free:
            colour = free[0]
        out[name] = colour
    return out


def units(recording: Recording) -> dict[str, str]:
    """Units of the FMU's variables, read from the recorded FMU when it is still there ({} if not)."""
    path = recording.metadata.get("fmu_bridge", {}).get("fmu")
    if not path or not Path(path).is_file():
        return {}
    try:
        from bridge.fmu.description import read_model_info

        info = read_model_info(path)
    except Exception:  # an unreadable FMU only costs the units on the axes
        return {}
    return {v.name: v.unit for v in info.variables.values() if v.unit}


def label(group: str, name: str, unit_of: Mapping[str, str]) -> str:
    """``force [N]`` for a physical stream, ``force (agent action, -1..1)`` for the raw action."""
    if group == meta.AGENT_ACTION:
        return f"{name} (agent action, -1..1)" if name != "index" else "action index"
    if group == meta.OBSERVATIONS:
        return f"{name} (observed, scaled)"
    unit = unit_of.get(name)
    return f"{name} [{unit}]" if unit else name


def config(recording: Recording) -> dict[str, Any]:
    text = recording.metadata.get("fmu_bridge", {}).get("config")
    try:
        data = yaml.safe_load(text) if text else {}
    except yaml.YAMLError:
        return {}
    return data if isinstance(data, dict) else {}


def tracking_pairs(cfg: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(output, reference) pairs: ``evaluation.metrics.tracking``, else the reward's tracking terms,
    else ``observations.errors``."""
    listed = (cfg.get("evaluation") or {}).get("metrics", {}).get("tracking") or []
    pairs = [(str(p[0]), str(p[1])) for p in listed if len(p) == 2]
    if not pairs:
        for term in (cfg.get("reward") or {}).get("terms", []):
            tracking = term.get("tracking") if isinstance(term, dict) else None
            if tracking:
                pairs.append((str(tracking["output"]), str(tracking["reference"])))
    if not pairs:
        errors = (cfg.get("observations") or {}).get("errors") or {}
        pairs = [(str(out), str(ref)) for ref, out in errors.items()]
    return pairs


def reference_values(
    cfg: Mapping[str, Any], recording: Recording, reference: str, episodes: npt.NDArray[np.int64],
    sim_time_s: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64] | None:  # fmt: skip
    """The reference of each row, rebuilt from the episode's scenario profile or drawn value."""
    from bridge.experiment.config import Profile
    from bridge.task.scenario import evaluate

    scenarios = cfg.get("scenarios") or {}
    out = np.full(len(sim_time_s), np.nan)
    found = False
    for ep in recording.episodes:
        rows = episodes == ep.index
        if reference in ep.drawn:
            out[rows], found = ep.drawn[reference], True
            continue
        profile = ((scenarios.get(ep.scenario or "") or {}).get("references") or {}).get(reference)
        if profile is None:
            continue
        try:
            out[rows] = evaluate(Profile.model_validate(profile), sim_time_s[rows], recording.path.parent)
            found = True
        except Exception:  # a profile that cannot be rebuilt here (e.g. a CSV left behind): no line
            continue
    return out if found else None
