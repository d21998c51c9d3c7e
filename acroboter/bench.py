"""Benchmark: `python -m acroboter.bench` (see --help).

For each method it times the control step (state and time in, u out: path evaluation, model terms,
linear algebra and input recovery all included) on the states of the real scenario, for
  (a) the compiled path: the generated C through pre-bound ctypes calls, and
  (b) the same solver fed by casadi.Function calls (what one writes without code generation),
in the same run; it times each method's whole closed-loop simulation (wall time, real-time
factor) and measures the memory the control step and the plant step allocate and keep
(tracemalloc). Prints a table and writes bench.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from .build import REPO

PAPER_MATLAB_US = {"mlm": 309.06, "penalty": 304.78, "iterative-3": 384.28, "iterative-4": 385.41,
                   "iterative-5": 410.62}
GOALS_US = {"mlm": 20.0, "penalty": 15.0, "iterative-5": 20.0}


def time_steps(controller, states, repeats: int) -> np.ndarray:
    """Per-call wall time (s) of controller.compute(q, q̇, t) over the states, `repeats` times."""
    clock = time.perf_counter
    compute = controller.compute
    times = np.empty(repeats * len(states))
    i = 0
    for _ in range(repeats):
        for q, qd, t in states:
            t0 = clock()
            compute(q, qd, t)
            times[i] = clock() - t0
            i += 1
    return times


def retained_bytes(fn, calls: int) -> float:
    """Bytes still allocated per call after `calls` calls (after a warm-up); 0 means nothing grows."""
    for _ in range(50):
        fn()
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for _ in range(calls):
        fn()
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    growth = sum(stat.size_diff for stat in after.compare_to(before, "filename"))
    return growth / calls


def stats(seconds: np.ndarray) -> dict:
    us = 1e6 * seconds
    return {"median": float(np.median(us)), "mean": float(us.mean()), "p99": float(np.percentile(us, 99))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m acroboter.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--spec", type=Path, default=REPO / "model_spec" / "acroboter.toml")
    parser.add_argument("--methods", default="mlm,penalty,iterative-3,iterative-4,iterative-5")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the scenario's states, path (a)")
    parser.add_argument("--casadi-states", type=int, default=500,
                        help="states timed on the casadi.Function path (b) (it is slow)")
    parser.add_argument("--out", type=Path, default=Path("results"), help="folder for bench.json")
    args = parser.parse_args(argv)

    from .casadi_backend import CasadiModel
    from .compiled import CompiledModel, StaleModelError
    from .controllers import Gains, make_controller
    from .simulation import setup_default, simulate
    from .spec import SpecError, load_spec
    from .statics import desired_path, solve_equilibrium

    try:
        spec = load_spec(args.spec)
        model = CompiledModel(spec)
    except (SpecError, StaleModelError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    gains = Gains.from_spec(spec)
    path = desired_path(model)
    start = solve_equilibrium(model, path)
    plant = setup_default(model, path)
    rate, h = spec.controller.rate_hz, spec.simulation.step
    reference = casadi_model = None
    results = {}
    print(f"benchmarking on {platform.processor() or platform.machine()}, {spec.name}, "
          f"{path.duration:g} s scenario ...", file=sys.stderr)
    for method in methods:
        controller = make_controller(method, model, path, gains)
        # Whole closed loop: the real scenario, also the source of the states to time.
        run = simulate(model, path, controller, plant, start.q, path.duration, rate, h)
        if reference is None:
            reference = run
        states = list(zip(run.q, run.qd, run.t, strict=True))
        compiled = time_steps(controller, states, args.repeats)
        if casadi_model is None:
            casadi_model = CasadiModel(spec)
        casadi_path = make_controller(method, casadi_model, desired_path(casadi_model), gains)
        stride = max(1, len(states) // args.casadi_states)
        casadi_times = time_steps(casadi_path, states[::stride], 1)
        # Same solver, other backend: the inputs must agree (to round-off of two evaluators).
        q, qd, t = states[len(states) // 2]
        agree = float(np.abs(casadi_path.compute(q, qd, t) - controller.compute(q, qd, t)).max())
        x = plant.initial_state(start.q)
        table = plant.stage_table(0.0, h, 1000)
        results[method] = {
            "compiled_us": stats(compiled),
            "casadi_function_us": stats(casadi_times),
            "speedup_median": float(np.median(casadi_times) / np.median(compiled)),
            "inputs_agree_max_abs": agree,
            "simulation_wall_s": run.sim_wall_s,
            "simulated_s": float(run.t[-1]),
            "real_time_factor": float(run.t[-1] / run.sim_wall_s),
            "retained_bytes_per_control_step": retained_bytes(lambda c=controller, s=states[100]: c.compute(*s),
                                                              2000),
            "retained_bytes_per_plant_step": retained_bytes(
                lambda x=x, u=run.u[0], table=table: plant.advance(x, u, h, table, 0, 1), 2000),
            "paper_matlab_mean_us": PAPER_MATLAB_US.get(method),
            "goal_median_us": GOALS_US.get(method),
        }
        print(f"  {method}: done", file=sys.stderr)

    print(format_table(results))
    args.out.mkdir(parents=True, exist_ok=True)
    doc = {
        "spec": spec.name,
        "machine": {"processor": platform.processor(), "machine": platform.machine(),
                    "python": platform.python_version(), "cores": _cores()},
        "date": time.strftime("%Y-%m-%d"),
        "methods": results,
    }
    (args.out / "bench.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(f"written {args.out / 'bench.json'}")
    return 0


def _cores() -> int | None:
    import os

    return os.cpu_count()


def format_table(results: dict) -> str:
    head = (f"{'method':<12} {'compiled median':>15} {'p99':>7} {'casadi.Function':>15} {'p99':>7} {'speed-up':>8} "
            f"{'MATLAB mean':>11} {'goal':>5} {'sim wall':>8} {'RTF':>5} {'kept B/step':>11}")
    units = (f"{'':<12} {'us':>15} {'us':>7} {'median us':>15} {'us':>7} {'x':>8} {'us':>11} {'us':>5} {'s':>8} "
             f"{'':>5} {'ctrl/plant':>11}")
    lines = [head, units, "-" * len(head)]
    for method, r in results.items():
        goal = r["goal_median_us"]
        paper = r["paper_matlab_mean_us"]
        lines.append(
            f"{method:<12} {r['compiled_us']['median']:15.1f} {r['compiled_us']['p99']:7.1f} "
            f"{r['casadi_function_us']['median']:15.1f} {r['casadi_function_us']['p99']:7.1f} "
            f"{r['speedup_median']:8.1f} {paper if paper else float('nan'):11.1f} "
            f"{goal if goal else float('nan'):5.0f} {r['simulation_wall_s']:8.2f} {r['real_time_factor']:5.0f} "
            f"{r['retained_bytes_per_control_step']:5.1f}/{r['retained_bytes_per_plant_step']:<5.1f}"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
