"""Issue 34 item 3 (planned in seconds): rest-to-rest edges are independent problems, solved side by side on the
usable cores (acroboter.planning.edges.EdgeRetiming._side_by_side; CasADi releases the GIL while IPOPT runs), then
flown in one chain, where an edge the carried swing takes beyond the bounds is solved again from there (`carried`).
Judged where a user meets it: the same plan, bit for bit, on one thread and on two; a Ctrl-C or an error on one
thread stops every solve; and the chained plan's inputs within the bounds at every millisecond."""

from __future__ import annotations

import re
import threading

import numpy as np
import pytest

import acroboter
import acroboter.planning.retiming as retiming
from acroboter.planning.edges import EdgeRetiming
from acroboter.process.locations import example_spec

TWO_EDGES = "waypoints = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.05], [0.0, 0.0, 0.1]]"


def two_edge_crane(tmp_path):
    text = re.sub(r'(cable = "L\d")', r"\1\nlimits = [24.0, 29.0]", example_spec("acroboter").read_text())
    text = re.sub(r"waypoints = \[.*?\n\]", TWO_EDGES, text, flags=re.S)
    path = tmp_path / "two.toml"
    path.write_text(text.replace("yaw_deg = 90.0", "yaw_deg = 0.0"))
    return acroboter.Crane.from_toml(path)


def test_edges_solved_side_by_side_are_the_edges_solved_one_by_one(tmp_path, monkeypatch):
    """The 0.1 m lift in two edges of 0.05 m (winches [24, 29] N, as tests/test_planning.py's oracle lift) planned on
    one thread and on two: the same timing, the same inputs, bit for bit (each edge's problem is the same whichever
    thread solves it), and the inputs within the limits less the margin on the plan's 1 ms check."""
    crane = two_edge_crane(tmp_path)
    plans = {}
    for workers in (1, 2):
        monkeypatch.setattr(retiming, "usable_cores", lambda workers=workers: workers)
        plans[workers] = crane.plan(margin=0.05, intervals=16, certify=False)
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
