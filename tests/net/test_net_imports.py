"""``bridge.net`` serves a plant and names: it never imports the task, typed-only imports counted."""

from __future__ import annotations

import pytest


def test_no_module_of_bridge_net_reaches_the_task_not_even_for_typing() -> None:
    """Every import counts here: at module level, inside functions and under TYPE_CHECKING (what
    the import contract sees once typed-only imports are counted). Composition that needs the
    task's names lives above the network, in ``bridge.serving``."""
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("bridge", exclude_type_checking_imports=False)
    net = sorted(m for m in graph.modules if m == "bridge.net" or m.startswith("bridge.net."))
    task = sorted(m for m in graph.modules if m == "bridge.task" or m.startswith("bridge.task."))
    assert net and task
    chains = {
        (importer, imported): graph.find_shortest_chain(importer=importer, imported=imported)
        for importer in net
        for imported in ("bridge.task.core", "bridge.task.expr", "bridge.task")
        if imported in task
    }
    reached = {pair: chain for pair, chain in chains.items() if chain}
    assert reached == {}, "bridge.net reaches the task through these chains"
