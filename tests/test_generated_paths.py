"""Paths nobody planned (acroboter.studies.generated_paths, `make plan-fuzz`): two- and three-edge paths drawn on the
default and the four-cable crane, winch limits drawn where the statics leave 5-20 % of the span, planned with
`--tolerance 0.1mm` and flown by every method with the limits applied.

The property test draws the paths through the generator's own function with hypothesis's numbers (so a failing
path shrinks); it plans PATH_EXAMPLES of them here (a plan to a tolerance takes minutes: the make target plans
more, tools/plan_fuzz.py). The flight it judges is its own: the plan's CSV read back as `acroboter run
--trajectory` reads it and flown by `crane.simulate` with the spec's limits, not the planner's certificate."""

from __future__ import annotations

import os

import numpy as np
import pytest
from crane_strategy import HypothesisDraw
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from acroboter.control.trajectory_file import read_trajectory_csv
from acroboter.model.spec_edits import with_winch_limits
from acroboter.studies import generated_paths as gp

PATH_EXAMPLES = int(os.environ.get("ACROBOTER_PATH_EXAMPLES", "1"))
STATIC_TENSION_N = 26.7538714  # the default crane's winches at rest at its start (tests/test_planning.py's oracle)


@st.composite
def paths(draw, specs=gp.SPECS):
    return gp.drawn_path(HypothesisDraw(draw), draw(st.sampled_from(specs)))


@settings(max_examples=200, deadline=None)
@given(path=paths())
def test_drawn_paths_keep_their_ranges(path):
    assert gp.EDGES[0] <= path.edges <= gp.EDGES[1]
    points = np.array(path.waypoints)
    assert np.all(points[0] == 0.0)
    steps = np.diff(points, axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    assert np.all(lengths >= gp.EDGE_LENGTH_M[0] * (1 - 1e-12)) and np.all(lengths <= gp.EDGE_LENGTH_M[1] * (1 + 1e-12))
    assert abs(path.yaw_deg) <= gp.YAW_DEG
    assert gp.STATIC_ROOM[0] <= path.static_room <= gp.STATIC_ROOM[1]
    text = path.spec_text()
    assert f"yaw_deg = {float(path.yaw_deg)!r}" in text


@settings(max_examples=4, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(path=paths(specs=("acroboter",)))
def test_drawn_limits_leave_the_drawn_room_above_the_statics(path, tmp_path):
    """The upper limit leaves `static_room` of the span above the largest static need; the start's need is the
    lift oracle's static tension, so the need range holds it."""
    lower, upper, least, largest = gp.winch_limits(path, tmp_path)
    assert lower == gp.LOWER_N
    assert (upper - largest) / (upper - lower) == pytest.approx(path.static_room, rel=1e-9)
    assert least - 1e-6 <= STATIC_TENSION_N <= largest + 1e-6
    crane = gp.crane_of(with_winch_limits(path.spec_text(), upper, lower), tmp_path / "limited.toml")
    limits = crane.input_limits()
    assert all(limits[f"tension_{i}"][:2] == (lower, upper) for i in (1, 2, 3))


# no shrinking: each example takes minutes; a failing one is printed as drawn (tools/plan_fuzz.py replays by seed)
@settings(max_examples=PATH_EXAMPLES, deadline=None, derandomize=True, phases=[Phase.explicit, Phase.generate],
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(path=paths())
def test_a_drawn_path_planned_to_a_tolerance_flies_within_it_off_every_limit(path, tmp_path):
    """The issue's acceptance on a drawn path: the plan meets 0.1 mm with every method at every clock phase, no
    instant on a limit, no planned input inside the margin on the 1 ms grid, faster than the best uniform slowdown
    of the time-optimal timing meeting 0.1 mm; and the written trajectory, flown again here, within 0.1 mm."""
    result = gp.run_path(path, "drawn", tmp_path)
    assert result.failures == [], result.failures
    assert result.planned_s < result.uniform_s
    assert result.time_optimal_s < result.planned_s  # the tolerance costs time; the jerk-free optimum is a bound
    crane = gp.crane_of((tmp_path / "spec.toml").read_text(), tmp_path / "again.toml")
    trajectory = read_trajectory_csv(tmp_path / "plan.csv")
    for method in gp.METHODS:
        flown = crane.simulate(method, trajectory=trajectory, warm_up=0)
        assert float(flown.position_error_mm.max()) <= 1e3 * gp.TOLERANCE_M
        assert not (flown.run.limit_state != 0).any()
        lower, upper, _ = crane.spec.input_limits()
        span = upper - lower
        finite = np.isfinite(span)
        gap = np.minimum(flown.u - lower, upper - flown.u)[:, finite] / span[finite]
        assert gap.min() >= 0.0
    assert result.margin_achieved >= gp.MARGIN * (1 - 1e-6)


def test_drawn_path_0s_third_edge_has_a_timing_once_each_corner_leaves_room_for_the_lag(tmp_path):
    """Kept from `tools/plan_fuzz.py` (seed 0: three edges on the default crane, 2026-12-07). A plan to a tolerance
    carries the lag model's state from edge to edge; when edge 2 could spend the whole 0.1 mm bound up to its end, it
    ended at 0.0987 mm with the lag still growing, and edge 3 had no timing (Infeasible_Problem_Detected: its own
    timing slowed from rest kept, the plan refused as not the fastest). With the free lag response bounded densely
    after each edge's end (servo_lag.LAG_SETTLE_TIMES_S) and within half the bound at a corner (CORNER_LAG_SHARE)
    every edge is solved: 92 s here (before the box below). With the whole bound at the corners (the share 1.0,
    tried) edge 3 is solved too, barely: the test passed in 661 s. Since the corners' box is 10 times the bound
    (1 mm here, the lag model's blind spot: retiming.REST_TOL_PER_LAG_BOUND) the edges take longer to solve; the
    whole tolerance search on this path then meets 0.1 mm in two rounds (10.85 s, flown at 0.0877 mm)."""
    from acroboter.model.crane_generator import RandomDraw
    from acroboter.planning.planner import plan
    from acroboter.planning.retiming import OPTIMAL

    path = gp.drawn_path(RandomDraw(0), "acroboter")
    assert path.edges == 3
    lower, upper, _, _ = gp.winch_limits(path, tmp_path)
    crane = gp.crane_of(with_winch_limits(path.spec_text(), upper, lower), tmp_path / "spec.toml")
    c = crane.spec.controller
    result = plan(crane.model.data(), crane.desired(), crane.equilibrium().q, margin=gp.MARGIN,
                  intervals=gp.INTERVALS, certify_plan=False, lag=(gp.TOLERANCE_M, c.kp, c.kd, 1.0 / c.rate_hz))
    statuses = [r["status"] for r in result.solves if not r.get("replaced")]
    assert len(statuses) >= 3 and all(s in OPTIMAL for s in statuses), statuses
    assert result.failures == []
