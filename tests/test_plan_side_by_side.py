"""Issue 34 item 3 (planned in seconds): rest-to-rest edges are independent problems, solved side by side on the
usable cores (acroboter.planning.edges.EdgeRetiming._side_by_side; CasADi releases the GIL while IPOPT runs), then
flown in one chain, where an edge the carried swing takes beyond the bounds is solved again from there (`carried`).
Judged where a user meets it: the same plan, bit for bit, on one thread and on two (and two threads did run); an
error on one thread stops every solve; the chained plan's inputs within the bounds at every millisecond; and the
mending's choices (the edge before solved again for a calmer corner, undone when it does not help) on scripted
edges: the paper's path, where it acts, takes 9 minutes to plan."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import acroboter
import acroboter.planning.retiming as retiming
from acroboter.model.spec_edits import with_path, with_winch_limits
from acroboter.planning.edges import Edge, EdgeRetiming
from acroboter.planning.ideal_motion import PlanningError, SolveFailed
from acroboter.process.locations import example_spec

TWO_EDGES = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.05], [0.0, 0.0, 0.1]]


def two_edge_crane(tmp_path):
    text = with_winch_limits(example_spec("acroboter").read_text(), 29.0, 24.0)
    path = tmp_path / "two.toml"
    path.write_text(with_path(text, TWO_EDGES, yaw_deg=0.0))
    return acroboter.Crane.from_toml(path)


def test_edges_solved_side_by_side_are_the_edges_solved_one_by_one(tmp_path, monkeypatch):
    """The 0.1 m lift in two edges of 0.05 m (winches [24, 29] N, as tests/test_planning.py's oracle lift) planned on
    one thread and on two: the same timing, the same inputs, bit for bit (each edge's problem is the same whichever
    thread solves it), and the inputs within the limits less the margin on the plan's 1 ms check."""
    crane = two_edge_crane(tmp_path)
    plans, threads = {}, {1: set(), 2: set()}
    solve_edge = EdgeRetiming._solve_edge
    for workers in (1, 2):
        def recorded(self, *args, workers=workers, **kwargs):
            threads[workers].add(threading.current_thread().name)
            return solve_edge(self, *args, **kwargs)

        monkeypatch.setattr(retiming, "usable_cores", lambda workers=workers: workers)
        monkeypatch.setattr(EdgeRetiming, "_solve_edge", recorded)
        plans[workers] = crane.plan(margin=0.05, intervals=16, certify=False)
    assert threads[1] == {"MainThread"} and len(threads[2]) == 2 and all(n.startswith("edge") for n in threads[2])
    one, two = plans[1], plans[2]
    assert [s["phases"] for s in one.solves] == [s["phases"] for s in two.solves]
    assert np.array_equal(one.times, two.times) and np.array_equal(one.inputs, two.inputs)
    assert one.duration == two.duration and one.status == two.status == "planned"
    low, high = one.bounds
    winches = one.inputs[:, :3]
    assert winches.max() <= high[0] + 1e-6 and winches.min() >= low[0] - 1e-6


class _Edges(EdgeRetiming):
    def __init__(self):  # only what _side_by_side reads
        self.workers, self.cancelled = 2, threading.Event()


def test_an_error_on_one_thread_stops_the_solve_on_the_other():
    """Edge 2 fails (a Ctrl-C reaching its solve, an internal error) while edge 1 is still solving: edge 1's solve
    sees `cancelled` (IPOPT's callback polls it every iteration, retiming._stopper) and stops, the error is raised
    in the caller, and the flag is cleared for the next plan."""
    problem = _Edges()
    seen = []

    def solved(j, lag):
        if j == 1:
            raise KeyboardInterrupt
        seen.append(problem.cancelled.wait(timeout=60.0))  # what _stopper polls
        return j

    with pytest.raises(KeyboardInterrupt):
        problem._side_by_side(solved, 2)
    assert seen == [True] and not problem.cancelled.is_set()


def test_one_core_solves_in_turn_on_the_callers_thread():
    problem = _Edges()
    problem.workers = 1
    threads = []
    assert problem._side_by_side(lambda j, lag: threads.append(threading.current_thread()) or j, 3) == [0, 1, 2]
    assert set(threads) == {threading.main_thread()}


def test_the_callback_stops_a_solve_when_the_plan_is_cancelled():
    event = threading.Event()
    stop = retiming._stopper(event)
    stop(0)  # nothing pending: the solve goes on
    event.set()
    with pytest.raises(KeyboardInterrupt):
        stop(1)


def _edge(name: str, status: str = "Solve_Succeeded") -> Edge:
    return Edge(np.array([1.0]), np.zeros(2), np.zeros(2), status, [{"phases": [0], "status": status, "name": name}],
                1, None, np.zeros(6), 2)


class _Chain(EdgeRetiming):
    """`carried`'s choices alone: each edge's mend, the backtrack's solve and its check scripted by name."""

    def __init__(self, mends: dict, backtrack: Edge | None, backtrack_excess: float = 0.0):
        self.mends, self.backtrack, self.backtrack_excess, self.lag, self.smooth = mends, backtrack, \
            backtrack_excess, None, False
        self.calls, self.rest_tol = [], 0.01

    def _start(self, x, j):
        return x

    def _mend(self, j, x, edge, counts, end, uniform_duration, verbose):
        results = self.mends[j]
        result = results.pop(0) if len(results) > 1 else results[0]
        self.calls.append(("mend", j, float(x[0])))
        return result[0], result[1], np.array([x[0] + 1.0]), f"scripted for edge {j + 1}" if result[1] > 0 else None

    def _solve_edge(self, j, *args, tail_s=0.0, **kwargs):
        self.calls.append(("tail", j, tail_s, self.rest_tol))
        if self.backtrack is None:
            raise PlanningError("Infeasible_Problem_Detected, scripted")
        return self.backtrack

    def swing_at(self, j, x):
        return 12.5, 13.2, "CC"

    def edge_excess(self, x, j, count, edge):
        return np.array([self.backtrack_excess]), np.array([-1.0]), np.array([x[0] + 10.0])


def test_the_edge_before_is_solved_again_with_a_calmer_corner_when_no_timing_holds_from_its_swing():
    """Edge 2 has no timing within the bounds from the swing edge 1 leaves; edge 1 solved again with its corner's
    hold bounded (CARRY_TAIL_S) is within them, and edge 2 mended from there holds: both kept, the replaced solve
    marked so (the plan's status reads the kept one), edge 3 mended from edge 2's end."""
    e = [_edge(f"e{j}") for j in range(3)]
    m1, m1_again, m2 = _edge("m1"), _edge("m1 again"), _edge("m2")
    before = _edge("e0 with its corner held")
    chain = _Chain({0: [(e[0], -1.0)], 1: [(m1, 0.1), (m1_again, 0.0)], 2: [(m2, 0.0)]}, before)
    out = chain.carried(np.zeros(1), [2, 2, 2], e, [None] * 3, 1.0, 10, False)
    assert [x.records[-1]["name"] for x in out] == ["e0 with its corner held", "m1 again", "m2"]
    assert out[0].records[0]["replaced"] and "replaced" not in e[0].records[0]  # the original left as it was
    from acroboter.planning.edges import CARRY_TAIL_S

    assert ("tail", 0, CARRY_TAIL_S, 0.01) in chain.calls
    assert chain.stuck is None
    assert chain.calls[-2:] == [("mend", 1, 10.0), ("mend", 2, 11.0)]  # edge 2 from the calmer corner, edge 3 after


def test_a_calmer_corner_that_does_not_help_is_undone_and_the_mending_stops():
    """The same, but edge 2 leaves the bounds by more from the calmer corner (0.2 against 0.1): edge 1 as it was,
    edge 2's first answer, and edge 3 not mended at all (the plan leaves the bounds whatever follows)."""
    e = [_edge(f"e{j}") for j in range(3)]
    m1, m1_again = _edge("m1"), _edge("m1 again")
    chain = _Chain({0: [(e[0], -1.0)], 1: [(m1, 0.1), (m1_again, 0.2)], 2: [(_edge("m2"), 0.0)]},
                   _edge("e0 with its corner held"))
    out = chain.carried(np.zeros(1), [2, 2, 2], e, [None] * 3, 1.0, 10, False)
    assert [x.records[-1]["name"] for x in out] == ["e0", "m1", "e2"]
    assert not any(c[:2] == ("mend", 2) for c in chain.calls)


def test_a_mending_that_finds_no_timing_says_which_edge_and_what_swing_in_the_plans_failure():
    """Edge 2 has no timing from edge 1's swing, and edge 1 solved again for a calmer corner has none either: the
    failed solve is in edge 1's records (marked: the plan's status does not read it), and
    `stuck` (which the plan's failure quotes instead of "give more --intervals") names the edge, the swing, the
    solver's reason and the calmer corner tried."""
    e = [_edge(f"e{j}") for j in range(3)]
    chain = _Chain({0: [(e[0], -1.0)], 1: [(_edge("m1"), 0.1)], 2: [(_edge("m2"), 0.0)]}, None)
    out = chain.carried(np.zeros(1), [2, 2, 2], e, [None] * 3, 1.0, 10, False)
    assert [x.records[-1].get("name") for x in out] == [None, "m1", "e2"]
    failed = out[0].records[-1]
    assert failed["status"] == "carried_swing_not_solved" and failed["replaced"] and "scripted" in failed["reason"]
    assert "edge 2 (from t = 1.000 s) has no timing that keeps the bounds from the swing edge 1 leaves" in chain.stuck
    assert "CC 12.5 mm from rest, 13.2 mm/s; scripted for edge 2)" in chain.stuck
    assert "nor after edge 1 was solved again for a calmer corner" in chain.stuck and "--shaper zvd" in chain.stuck
    from acroboter.planning.planner import between_nodes

    said = between_nodes(np.array([0.0, 9.004]), np.array([[20.0], [31.5866]]), np.array([6.25]),
                         np.array([28.75]), ["tension_1"], ["N"], chain.stuck)
    assert "with the swing carried over every corner: tension_1 = 31.5866 N at t = 9.004 s" in said
    assert "--intervals" not in said and chain.stuck in said


def test_a_first_edge_with_no_timing_is_not_blamed_on_a_carried_swing():
    chain = _Chain({0: [(_edge("m0"), 0.1)], 1: [(_edge("m1"), 0.0)]}, None)
    chain.carried(np.zeros(1), [2, 2], [_edge("e0"), _edge("e1")], [None] * 2, 1.0, 10, False)
    assert chain.stuck is None  # nothing carried in: the plan's leak between nodes, "give more --intervals"


class _Mend(_Chain):
    """`_mend` alone: an edge 0.1 of the span beyond its bounds wherever it starts, re-solved by `answer` (a
    PlanningError to raise or an Edge to return)."""

    def __init__(self, answer):
        super().__init__({}, None)
        self.answer, self.lower, self.upper = answer, np.array([6.25]), np.array([28.75])

    def at_rest(self, j, q=None):
        return np.ones(1)

    def edge_excess(self, x, j, count, edge):
        return np.array([0.1]), np.array([-1.0]), np.array([x[0] + 1.0])

    def _solve_edge(self, j, *args, **kwargs):
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def test_a_mend_with_no_timing_gives_ipopts_status_not_the_from_rest_advice():
    """_mend's reason is IPOPT's status: the solver's own advice (more intervals, a larger margin) is for a plan
    from rest, not for a swing carried in; the failed solve is kept in the edge's records, the bounds restored."""
    chain, edge = _Mend(SolveFailed("Infeasible_Problem_Detected after 89 iterations", 38.91)), _edge("e1")
    kept, beyond, _, why = EdgeRetiming._mend(chain, 1, np.zeros(1), edge, [2, 2], None, 1.0, False)
    assert kept is edge and beyond == 0.1 and why == "IPOPT: Infeasible_Problem_Detected after 89 iterations"
    assert edge.records[-1]["status"] == "carried_swing_not_solved" and "--intervals" in edge.records[-1]["reason"]
    assert chain.lower[0] == 6.25 and chain.upper[0] == 28.75


def test_a_mend_out_of_iterations_is_no_timing_and_says_so():
    """IPOPT out of iterations at a feasible point returns that point (Retiming._solved), status not optimal: the
    mend is stuck, as a failed solve is, the status and iterations its reason, the attempt recorded."""
    edge = _edge("e1")
    chain = _Mend(_edge("out of iterations", "Maximum_Iterations_Exceeded"))
    kept, _, _, why = EdgeRetiming._mend(chain, 1, np.zeros(1), edge, [2, 2], None, 1.0, False)
    assert kept is edge and why == "IPOPT: Maximum_Iterations_Exceeded after 1 iterations"
    assert edge.records[-1]["status"] == "carried_swing_not_solved" and edge.records[-1]["replaced"]


def test_an_edge_solve_without_a_fallback_raises_what_ipopt_said():
    """_solve_edge with no fallback (the mending's re-solves) raises the solve's PlanningError for the caller to
    record, where one with a fallback keeps that timing (quintic_slowdown_kept)."""

    class Failing(_Chain):
        def solve_phases(self, *args, **kwargs):
            raise PlanningError("the time-optimal problem was not solved (Infeasible_Problem_Detected after 7 "
                                "iterations)")

    chain = Failing({}, None)
    args = (0, [2], np.zeros(1), (np.zeros(2), 1.0))
    with pytest.raises(PlanningError, match="Infeasible_Problem_Detected"):
        EdgeRetiming._solve_edge(chain, *args, None, None, 1.0, 10, False, np.zeros(6))
    kept = EdgeRetiming._solve_edge(chain, *args, (np.zeros(2), 2.0), None, 1.0, 10, False, np.zeros(6))
    assert kept.status == "quintic_slowdown_kept" and float(kept.durations[0]) == 2.0


def test_a_backtrack_that_still_leaves_the_bounds_is_not_kept():
    e = [_edge(f"e{j}") for j in range(2)]
    chain = _Chain({0: [(e[0], -1.0)], 1: [(_edge("m1"), 0.1)]}, _edge("e0 held"), backtrack_excess=0.05)
    out = chain.carried(np.zeros(1), [2, 2], e, [None] * 2, 1.0, 10, False)
    assert [x.records[-1]["name"] for x in out] == ["e0", "m1"]


def test_the_mendings_input_check_integrates_each_edge_from_its_start_only(tmp_path):
    """The mending's 1 ms check (EdgeRetiming.edge_inputs) flies an edge's timing again from the edge's start, the
    whole way, as the plan's own check does (Retiming.inputs_on_grid): not from each node state, which carries the
    solve's RK4 error (that error put a jerk-bounded lift's input 1.65 mN past the bound the plan kept). Edge 1 of
    the two-edge lift on its own timing slowed 2x, σ̈ made linear per interval: node states from one RK4 step per
    interval (a coarse solve's) and from the 1 ms steps give the same inputs, bit for bit, and they are the plan
    check's."""
    from acroboter.planning.geometry import PathGeometry
    from acroboter.planning.ideal_motion import IdealDynamics
    from acroboter.planning.retiming import Solution
    from acroboter.planning.windows import _warm

    crane = two_edge_crane(tmp_path)
    q0 = crane.equilibrium().q
    low, high, _ = crane.spec.input_limits()
    problem = EdgeRetiming(IdealDynamics(crane.spec, q0), PathGeometry(crane.desired()), q0, low, high)
    count = 8
    acc, duration = _warm(problem, 0, count, 2.0)
    jerk = np.diff(np.append(acc, 0.0)) / (duration / count)  # σ̈ linear per interval, to 0 at the corner
    edge = Edge(np.array([duration]), acc, jerk, "Solve_Succeeded", [], 0, None, np.zeros(6), 1)
    start = problem.at_rest(0)
    coarse, _ = problem.run_grid(start, acc, duration / count, 1, jerk=jerk)
    fine, _ = problem.run_grid(start, acc, duration / count, 200, jerk=jerk)
    assert np.abs(coarse - fine).max() > 1e-9  # the node states differ: the coarse ones carry RK4's error
    from_coarse, from_fine = problem.edge_inputs(coarse, count, edge), problem.edge_inputs(fine, count, edge)
    assert np.array_equal(from_coarse, from_fine)
    times = np.linspace(0.0, duration, count + 1)
    whole = Solution(duration, times, coarse, acc, times[:-1], from_coarse[:-1], "Solve_Succeeded", 0, 0.0, 1.0,
                     duration, tau_ddd=jerk)
    _, checked = problem.inputs_on_grid(whole, 1e-3)
    assert checked.shape == from_coarse.shape
    np.testing.assert_allclose(checked[:-1], from_coarse[:-1], rtol=0, atol=1e-12)
