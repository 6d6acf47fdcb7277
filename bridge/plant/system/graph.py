"""The connection graph: direct feedthrough, algebraic loops, initialisation and Gauss-Seidel order.

A component has *direct feedthrough* when one of its outputs depends on an input at the same
instant. Values cross a connection ``a -> b`` within one instant only where ``a`` has feedthrough,
so a cycle of connections through feedthrough components only is an *algebraic loop*: no order
of the components gives consistent values at initialisation, and a master without fixed-point
iteration cannot solve it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from bridge.errors import ConfigError
from bridge.fmu.vocab import ModelInfo
from bridge.plant.system.description import Component, Connection, SystemDescription


def has_feedthrough(component: Component, info: ModelInfo) -> bool:
    """The component's ``feedthrough`` setting, else the FMU's declared output dependencies;
    FMI says an output without declared dependencies depends on every input."""
    if component.feedthrough is not None:
        return component.feedthrough
    inputs = {v.name for v in info.by_causality("input")}
    if not inputs:
        return False
    outputs = getattr(info.raw, "outputs", None)
    if not outputs:
        return True
    for unknown in outputs:
        dependencies = getattr(unknown, "dependencies", None)
        if dependencies is None or any(getattr(d, "name", None) in inputs for d in dependencies):
            return True
    return False


def _edges(system: SystemDescription, through: Mapping[str, bool]) -> dict[str, list[Connection]]:
    """Connections that carry a value within one instant, by source component."""
    edges: dict[str, list[Connection]] = {name: [] for name in system.components}
    for c in system.connections:
        if through[c.source.component]:
            edges[c.source.component].append(c)
    return edges


def find_loop(system: SystemDescription, through: Mapping[str, bool]) -> list[Connection] | None:
    """One algebraic loop as the connections around it, or None."""
    edges = _edges(system, through)
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[Connection] = []

    def visit(node: str) -> list[Connection] | None:
        state[node] = 1
        for c in edges[node]:
            nxt = c.target.component
            if not through[nxt]:
                continue
            if state.get(nxt) == 1:
                start = next(i for i, p in enumerate([*path, c]) if p.source.component == nxt)
                return [*path, c][start:]
            if nxt not in state:
                path.append(c)
                found = visit(nxt)
                if found:
                    return found
                path.pop()
        state[node] = 2
        return None

    for name in system.components:
        if name not in state and through[name]:
            loop = visit(name)
            if loop:
                return loop
    return None


def loop_error(loop: Sequence[Connection], system: SystemDescription) -> ConfigError:
    cycle = ", ".join(str(c) for c in loop)
    return ConfigError(
        f"algebraic loop: {cycle} (every component on it has direct feedthrough); "
        f"{system.algorithm} without iteration cannot solve it: set system.iteration "
        f"(fixed-point iteration with rollback), or set feedthrough: false on a component whose "
        f"outputs do not depend on its inputs at the same instant{system.where}"
    )


def init_order(system: SystemDescription, through: Mapping[str, bool]) -> list[str]:
    """Components without feedthrough first, then the others in topological order, so that
    each component starts from the values its sources hold at the start time."""
    first = [n for n in system.components if not through[n]]
    return first + _topological([n for n in system.components if through[n]], _edges(system, through))


def gauss_seidel_order(system: SystemDescription, through: Mapping[str, bool]) -> list[str]:
    """The given ``order``, else sources before their consumers; in a cycle, declaration order
    among components whose same-instant inputs are already known."""
    names = list(system.components)
    if system.order:
        if sorted(system.order) != sorted(names):
            raise ConfigError(
                f"system.order: {list(system.order)} must list every component once; "
                f"components: {names}{system.where}"
            )
        return list(system.order)
    every: dict[str, list[Connection]] = {n: [] for n in names}
    for c in system.connections:
        every[c.source.component].append(c)
    same_instant = _edges(system, through)
    order: list[str] = []
    remaining = list(names)
    while remaining:
        pick = _free(remaining, every) or _free(remaining, same_instant) or remaining[0]
        order.append(pick)
        remaining.remove(pick)
    return order


def _free(remaining: list[str], edges: Mapping[str, list[Connection]]) -> str | None:
    fed = {c.target.component for n in remaining for c in edges[n] if c.target.component != n}
    return next((n for n in remaining if n not in fed), None)


def _topological(names: list[str], edges: Mapping[str, list[Connection]]) -> list[str]:
    order: list[str] = []
    remaining = list(names)
    while remaining:
        pick = _free(remaining, edges) or remaining[0]  # a loop: caught by find_loop
        order.append(pick)
        remaining.remove(pick)
    return order


def to_dot(system: SystemDescription, through: Mapping[str, bool]) -> str:
    """The connection graph in Graphviz DOT; feedthrough components drawn as boxes."""
    lines = ["digraph system {", "  rankdir=LR;"]
    for name, comp in system.components.items():
        shape = "box" if through[name] else "ellipse"
        lines.append(f'  "{name}" [shape={shape}, label="{name}\\n{comp.fmu.name}"];')
    for c in system.connections:
        label = f"{c.source.variable} -> {c.target.variable}"
        lines.append(f'  "{c.source.component}" -> "{c.target.component}" [label="{label}"];')
    lines.append("}")
    return "\n".join(lines) + "\n"
