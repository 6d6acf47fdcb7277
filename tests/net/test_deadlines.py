"""``bridge.net.deadlines``: how long a client waits for a node, from its settings and measurements."""

from __future__ import annotations

import math

import pytest

from bridge.errors import ConfigError
from bridge.net.deadlines import RESET_MARGIN, STEP_MARGIN, Deadlines


def test_without_measurements_the_deadline_is_the_floor_or_the_nodes_own_plus_slack() -> None:
    assert Deadlines(5.0).step_s() == 5.0 and Deadlines(5.0).reset_s() == 5.0
    assert Deadlines(5.0, node_s=10.0).step_s() == 12.5  # 10 s + a quarter of it
    assert Deadlines(5.0, node_s=2.0).step_s() == 5.0  # 2 s + 1 s (the least slack) is under the floor
    assert Deadlines(1.0, node_s=2.0).reset_s() == 3.0


def test_measured_answers_raise_the_deadline_by_their_margin_and_never_lower_it() -> None:
    deadlines = Deadlines(5.0, node_s=10.0)
    deadlines.stepped(6.0)
    deadlines.stepped(0.5)  # a faster answer later: the slowest one counts
    deadlines.reset_took(30.0)
    assert deadlines.step_s() == STEP_MARGIN * 6.0
    assert deadlines.reset_s() == RESET_MARGIN * 30.0
    assert Deadlines(5.0).step_s() == 5.0  # each client measures its own node


def test_the_explanation_names_every_figure_and_the_settings() -> None:
    deadlines = Deadlines(5.0, node_s=10.0)
    assert deadlines.explain("reset") == (
        "the deadline 12.5 s is the longest of timeout_s = 5 s, the node's own deadline 10 s + 2.5 s, "
        "4 x the slowest reset measured (none yet)"
    )
    deadlines.stepped(7.25)
    assert deadlines.explain("step").startswith("the deadline 29 s is the longest of timeout_s = 5 s")
    assert "4 x the slowest step measured (7.25 s)" in deadlines.explain("step")
    assert "node's own deadline" not in Deadlines(5.0).explain("step")


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, math.nan])
def test_a_floor_that_is_not_a_positive_number_of_seconds_is_refused(bad: float) -> None:
    with pytest.raises(ConfigError, match=r"timeout_s must be a finite number of seconds > 0, got"):
        Deadlines(bad)


def test_a_node_deadline_that_is_not_finite_is_ignored() -> None:
    assert Deadlines(5.0, node_s=math.inf).step_s() == 5.0
    assert Deadlines(5.0, node_s=-3.0).step_s() == 5.0
