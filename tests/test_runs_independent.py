"""Runs on one Crane are independent (issue 35 item 1): the compiled model is shared, each run works on its own
copy of the buffers (CompiledModel.data()). An own-plant open-loop run, a MuJoCo open-loop run and a closed-loop run
on one crane, in both orders and in two threads at once, give every reported figure bit for bit as each run alone in
a fresh process; the open-loop tracking error is the distance between the tracked point and the path, computed here
from the recorded coordinates.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import acroboter

RUNS = ("own_open_loop", "mujoco_open_loop", "closed_loop")
SCRIPT = r"""
import json, sys
import numpy as np
sys.path.insert(0, {tests!r})
from test_runs_independent import run, figures
import acroboter
crane = acroboter.Crane.from_example("acroboter")
print(json.dumps(figures(run(crane, sys.argv[1]))))
"""


def inputs(crane):
    """The static inputs with winch 1 swung at 2 Hz by 1.5 N: the swinging unit moves."""
    static = crane.equilibrium().inputs.copy()

    def u(t):
        row = static.copy()
        row[0] += 1.5 * np.sin(2 * np.pi * 2.0 * t)
        return row

    return u


def run(crane, which: str):
    if which == "closed_loop":
        return crane.simulate("penalty", duration=1.0, warm_up=0)
    return crane.simulate_open_loop(inputs(crane), 1.0, plant="own" if which == "own_open_loop" else "mujoco")


def figures(result) -> dict:
    """Every reported figure, floats as exact hex strings, arrays by their bytes' hex digest."""
    import hashlib

    def exact(value):
        if isinstance(value, float):
            return value.hex()
        if isinstance(value, dict):
            return {k: exact(v) for k, v in value.items() if k not in ("control_step_us", "sim_wall_s")}
        if isinstance(value, list):
            return [exact(v) for v in value]
        return value

    arrays = {"q": result.q, "qd": result.qd, "u": result.u, "position_error_mm": result.position_error_mm,
              "tension": result.cable_tension}
    return {"summary": exact(result.summary()),
            "arrays": {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest() for k, v in arrays.items()}}


@pytest.fixture(scope="module")
def alone():
    """Each run alone in a fresh process."""
    tests = str(Path(__file__).resolve().parent)
    out = {}
    for which in RUNS:
        done = subprocess.run([sys.executable, "-c", SCRIPT.format(tests=tests), which], capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        out[which] = json.loads(done.stdout.strip().splitlines()[-1])
    return out


@pytest.mark.needs_mujoco
def test_runs_in_either_order_are_each_alone(alone):
    for order in (RUNS, RUNS[::-1]):
        crane = acroboter.Crane.from_example("acroboter")
        for which in order:
            assert figures(run(crane, which)) == alone[which], f"{which} after {order[: order.index(which)]}"


@pytest.mark.needs_mujoco
def test_runs_in_two_threads_are_each_alone(alone):
    crane = acroboter.Crane.from_example("acroboter")
    crane.equilibrium(), crane.path  # noqa: B018 (made before the threads: both read them)
    for pair in (("closed_loop", "own_open_loop"), ("own_open_loop", "mujoco_open_loop")):
        results, errors = {}, []

        def work(which, results=results, errors=errors):
            try:
                results[which] = figures(run(crane, which))
            except Exception as err:  # noqa: BLE001 (reported below)
                errors.append(err)

        threads = [threading.Thread(target=work, args=(which,)) for which in pair]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, errors
        for which in pair:
            assert results[which] == alone[which], f"{which} beside {pair}"


@pytest.mark.parametrize("plant", ["own", pytest.param("mujoco", marks=pytest.mark.needs_mujoco)])
def test_the_open_loop_error_is_the_tracked_points_distance_from_the_path(plant):
    crane = acroboter.Crane.from_example("acroboter")
    crane.simulate("penalty", duration=0.5, warm_up=0)  # a run before: nothing of it may show in the next
    result = crane.simulate_open_loop(inputs(crane), 1.0, plant=plant)
    offset = crane.layout.body_offset["SU"]
    tracked = result.q[:, offset : offset + 3]
    expected = 1e3 * np.linalg.norm(tracked - result.desired_position, axis=1)
    assert np.allclose(result.position_error_mm, expected, rtol=1e-12, atol=1e-12)
    assert expected.max() > 1.0  # the swinging unit moved: the figure is not zero by accident
