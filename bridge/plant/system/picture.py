"""A PNG of a system's connection graph, drawn with matplotlib (components on a circle)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from bridge.plant.system.description import SystemDescription


def draw_graph(system: SystemDescription, through: Mapping[str, bool], path: Path) -> None:
    """Components as boxes (feedthrough) or rounded boxes, connections as labelled arrows."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(system.components)
    at = {
        n: (math.cos(2 * math.pi * i / len(names)), math.sin(2 * math.pi * i / len(names)))
        for i, n in enumerate(names)
    }
    fig, ax = plt.subplots(figsize=(7, 6))
    for c in system.connections:
        (x0, y0), (x1, y1) = at[c.source.component], at[c.target.component]
        style = "arc3,rad=0.2"
        arrow = {"arrowstyle": "-|>", "connectionstyle": style, "shrinkA": 28, "shrinkB": 28}
        ax.annotate("", (x1, y1), (x0, y0), arrowprops=arrow)
        length = math.hypot(x1 - x0, y1 - y0) or 1.0
        dx, dy = (y1 - y0) / length * 0.12, -(x1 - x0) / length * 0.12  # beside its own arc
        label = f"{c.source.variable} -> {c.target.variable}"
        side = "left" if dx > 0.01 else "right" if dx < -0.01 else "center"
        ax.text(
            (x0 + x1) / 2 + dx,
            (y0 + y1) / 2 + dy,
            label,
            fontsize=8,
            ha=side,
            zorder=5,
            bbox={"fc": "white", "ec": "none", "alpha": 0.8},
        )
    for n, (x, y) in at.items():
        box = "square,pad=0.5" if through[n] else "round,pad=0.5"
        label = f"{n}\n{system.components[n].fmu.name}"
        ax.text(x, y, label, ha="center", va="center", bbox={"boxstyle": box, "fc": "#e8f0fe"})
    ax.set_xlim(-1.6, 1.6)
    ax.set_ylim(-1.6, 1.6)
    ax.axis("off")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
