"""Benchmark: `python -m acroboter.bench` (see --help).

For each method it times the control step (state and time in, u out: path evaluation, model terms,
linear algebra and input recovery all included) on the states of the real scenario, for
  (a) the compiled path: the generated C through pre-bound ctypes calls, and
  (b) the same solver fed by casadi.Function calls (what one writes without code generation),
in the same run; it times each method's whole closed-loop simulation (wall time, real-time
factor) and measures the memory the control step and the plant step allocate and keep
(tracemalloc). Prints a table and writes bench.json.

It also times what input limits cost (--limits-spec, default the four-cable crane): each method's
control step on that crane's states (a) with its limits (5..300 N, never reached on the path: the
distribution of the internal force and the bound check), (b) without limits, and (c) with every
winch's max at 99 % of its static tension, so the bounded QP (DAQP) runs at every step.

And, per method in the same interleaved passes, the Python step on its reference and its fast path, the
exported C step compiled and called in-process, their ratios and the estimator's cost (p50, p99, max); the
closed loop's real-time factor with and without sensing; the Monte Carlo throughput (acroboter.cli.bench_steps).
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

from ..model.ranges import CASADI_STATES, MC_SAMPLES, REPEATS
from ..model.spec import MAX_ITERATIONS
from ..process.locations import example_spec
from ..report.paper import PAPER_MATLAB_US
from .entry import guarded, ranged, spec_file
from .outputs import ResultsFolder, out_path, results_folder

GOALS_US = {"mlm": 20.0, "penalty": 15.0, "iterative-5": 20.0}
MIN_INSTANTS = 101  # the allocation check steps from instant 100 of the scenario


def time_steps(controller, states, repeats: int) -> np.ndarray:
    """Per-call wall time (s) of controller.compute(q, q̇, t) over the states: one row per pass."""
    clock = time.perf_counter
    compute = controller.compute
    times = np.empty((repeats, len(states)))
    for r in range(repeats):
        row = times[r]
        for i, (q, qd, t) in enumerate(states):
            t0 = clock()
            compute(q, qd, t)
            row[i] = clock() - t0
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
    """median, mean, p99 in µs. With several passes (rows), the figures of the quietest pass (the
    lowest median): on a shared 2-core machine other work inflates whole stretches of a pass, and
    the best pass is the repeatable figure (as timeit takes the minimum)."""
    us = 1e6 * np.atleast_2d(seconds)
    best = us[np.argmin(np.median(us, axis=1))]
    return {"median": float(np.median(best)), "mean": float(best.mean()), "p99": float(np.percentile(best, 99)),
            "passes": int(us.shape[0]), "median_all_passes": float(np.median(us))}


@guarded
def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="acroboter bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--spec", type=spec_file, default=example_spec("acroboter"),
                        help="model spec whose scenario is timed: a TOML file or an example's name (acroboter "
                             "examples) (default: %(default)s)")
    parser.add_argument("--method", "--methods", dest="methods",
                        default="mlm,penalty,iterative-3,iterative-4,iterative-5",
                        help="comma-separated methods: mlm, penalty, iterative-N (default: %(default)s)")
    parser.add_argument("--repeats", type=ranged(REPEATS), default=5, help="passes over the scenario's states (1..100)")
    parser.add_argument("--casadi-states", type=ranged(CASADI_STATES), default=500,
                        help="states timed on the casadi.Function path (b) (it is slow)")
    parser.add_argument("--mc-samples", type=ranged(MC_SAMPLES), default=2,
                        help="plants of the default robustness study whose 20 s runs (every method, with and without "
                             "integral action, reference and fast path) give the Monte Carlo throughput (0..200, 0: "
                             "skip; default: %(default)s)")
    parser.add_argument("--limits-spec", type=Path, default=example_spec("acroboter_4cable"),
                        help="crane on which the cost of input limits is timed (default: %(default)s)")
    parser.add_argument("--out", type=out_path, default=Path("results"), help="folder for bench.json")
    args = parser.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for m in methods:
        if m not in ("mlm", "penalty") and not (m.startswith("iterative-") and m[10:].isdigit()
                                                and 1 <= int(m[10:]) <= MAX_ITERATIONS):
            parser.error(f"unknown method '{m}': use mlm, penalty or iterative-N (1 <= N <= {MAX_ITERATIONS})")
    if not methods:
        parser.error("--methods names no method")
    with results_folder(args.out, "bench", expected=["bench.json"]) as folder:  # checked before any work
        return _bench(args, methods, folder)


class _CannotTime(Exception):
    """The benchmark cannot run as asked: the text (printed as 'error: …') and the exit status."""

    def __init__(self, text: str, status: int):
        super().__init__(text)
        self.status = status


def _bench(args: argparse.Namespace, methods: list[str], folder: ResultsFolder) -> int:
    """The phases: the crane loaded and checked, the model terms timed, the methods that run on it, their closed
    loops and control steps timed (against the casadi.Function path), the limits, the step forms, the loops and the
    Monte Carlo, the plant's step; bench.json written."""
    from ..control.controllers import SingularSystemError
    from ..model.spec import SpecError
    from ..runtime.compiled import StaleModelError
    from ..sim.plant import SimulationError

    try:
        crane, start = _loaded(args)
        print(f"benchmarking on {_processor()}, {crane.spec.name}, {crane.path.duration:g} s scenario ...",
              file=sys.stderr)
        model_terms_us = time_model_terms(crane.model, start.q, crane.path)
        controllers = runnable_controllers(crane, methods, start)
        methods = list(controllers)
        runs, walls = _closed_loops(crane, controllers, start)
    except _CannotTime as err:
        print(f"error: {err}", file=sys.stderr)
        return err.status
    results, states = _step_results(args, crane, controllers, runs, walls, start)
    print(format_table(results))
    print(f"all model terms at one state (model_terms, one ctypes call): median {model_terms_us['median']:.2f} us, "
          f"p99 {model_terms_us['p99']:.2f} us")
    try:
        limits = bench_limits(args.limits_spec, methods, args.repeats)
    except (SpecError, StaleModelError, SimulationError, SingularSystemError) as err:
        print(f"error: cannot time the input limits on {args.limits_spec}: {err}", file=sys.stderr)
        return 3
    print(format_limits_table(limits))
    from .bench_steps import bench_loops, bench_monte_carlo, bench_steps, format_steps

    steps = bench_steps(crane, methods, states, args.repeats)
    loops = bench_loops(crane, methods)
    mc = bench_monte_carlo(crane, methods, args.mc_samples) if args.mc_samples else None
    print(format_steps(steps, loops, mc))
    plant_step = bench_plant_step(crane, start.q, start.inputs)
    print(f"plant RK4 step (one ctypes call): spec's numbers folded in {plant_step['folded_us']:.2f} us, physical "
          f"parameters as an input {plant_step['parametric_us']:.2f} us (x{plant_step['ratio']:.2f}, quietest of "
          f"{plant_step['passes']} interleaved passes)")
    doc = {
        "spec": crane.spec.name,
        "machine": {"processor": _processor(), "machine": platform.machine(),
                    "python": platform.python_version(), "cores": _cores()},
        "date": time.strftime("%Y-%m-%d"),
        "model_terms_us": model_terms_us,
        "methods": results,
        "limits": limits,
        "plant_step": plant_step,
        "steps": steps,
        "closed_loop": loops,
        "monte_carlo": mc,
    }
    (folder.staging / "bench.json").write_text(json.dumps(doc, indent=2) + "\n")
    folder.publish()
    print(f"written {args.out / 'bench.json'}")
    return 0


def _loaded(args: argparse.Namespace):
    """The crane (and the limits' spec) validated, a scenario long enough, its static start."""
    from ..api.crane import Crane
    from ..model.spec import SpecError, load_spec
    from ..runtime.compiled import StaleModelError

    try:
        load_spec(args.limits_spec)  # validated before any work too
        crane = Crane.from_toml(args.spec)
    except (SpecError, StaleModelError) as err:
        raise _CannotTime(str(err), 2) from None
    path, rate = crane.path, crane.spec.controller.rate_hz
    if path.duration * rate < MIN_INSTANTS:
        raise _CannotTime(f"the scenario of {crane.spec.name} has {path.duration * rate:.0f} control instants, the "
                          f"benchmark needs at least {MIN_INSTANTS}: lengthen the path (or lower path.mean_speed)", 2)
    return crane, crane.equilibrium()


def time_model_terms(model, q: np.ndarray, path) -> dict:
    """Every model term (M, c, φ, φ_q, φ̇, γ, σ, σ_q, σ̇, γ_s, H) at one state: one pre-bound C call, timed."""
    terms = model.functions["model_terms"]
    model.set_inputs(q, np.zeros(model.layout.n), *path.signal_arrays(3.0))
    clock = time.perf_counter
    samples = np.empty((5, 4000))
    for row in samples:
        for i in range(row.size):
            t0 = clock()
            terms.call()
            row[i] = clock() - t0
    return stats(samples)


def runnable_controllers(crane, methods: list[str], start) -> dict:
    """{method: controller} of the methods that run on this crane; one that cannot is left out, with its reason."""
    from ..control.controllers import SingularSystemError, make_controller
    from ..control.recovery import RecoveryError

    controllers = {}
    for m in methods:
        try:
            controllers[m] = make_controller(m, crane.model, crane.path, crane.gains())
            controllers[m].compute(start.q, np.zeros(crane.layout.n), 0.0)
        except (SingularSystemError, RecoveryError) as err:
            controllers.pop(m, None)
            print(f"  {m} left out: {err}", file=sys.stderr)
    if not controllers:
        raise _CannotTime("no method can run on this spec", 3)
    return controllers


def _closed_loops(crane, controllers: dict, start) -> tuple[dict, dict]:
    """Whole closed loops, best of 3 (interleaved, so a slow stretch of the machine hits all alike)."""
    from ..sim.plant import SimulationError
    from ..sim.simulation import setup_default, simulate

    spec, path = crane.spec, crane.path
    plant = setup_default(crane.model, path)
    runs, walls = {}, {m: [] for m in controllers}
    try:
        for _ in range(3):
            for m, controller in controllers.items():
                runs[m] = simulate(crane.model, path, controller, plant, start.q, path.duration,
                                   spec.controller.rate_hz, spec.simulation.step)
                walls[m].append(runs[m].sim_wall_s)
    except SimulationError as err:
        raise _CannotTime(f"the scenario does not run to the end, nothing to time: {err}", 3) from None
    return runs, walls


def _step_results(args, crane, controllers: dict, runs: dict, walls: dict, start) -> tuple[dict, list]:
    """Per method the compiled and casadi.Function control steps on the states of the real scenario (the first
    method's run), whether they agree, the loop's real-time factor, the bytes retained per step; and those states."""
    from ..control.controllers import make_controller
    from ..runtime.casadi_backend import CasadiModel
    from ..sim.simulation import setup_default
    from ..sim.statics import desired_path

    methods, h = list(controllers), crane.spec.simulation.step
    casadi_model = CasadiModel(crane.spec)
    casadi_path = desired_path(casadi_model)
    slow = {m: make_controller(m, casadi_model, casadi_path, crane.gains()) for m in methods}
    reference = runs[methods[0]]
    states = list(zip(reference.q, reference.qd, reference.t, strict=True))
    stride = max(1, len(states) // args.casadi_states)
    fast_times = {m: [] for m in methods}
    slow_times = {m: [] for m in methods}
    for r in range(args.repeats):  # interleaved passes, as above
        for m in methods:
            fast_times[m].append(time_steps(controllers[m], states, 1)[0])
            if r < 3:
                slow_times[m].append(time_steps(slow[m], states[::stride], 1)[0])
    plant = setup_default(crane.model, crane.path)
    x = plant.initial_state(start.q)
    table = plant.stage_table(0.0, h, 1000)
    results = {}
    for method in methods:
        controller = controllers[method]
        # Same solver, other backend: the inputs must agree (to round-off of two evaluators).
        q, qd, t = states[len(states) // 2]
        agree = float(np.abs(slow[method].compute(q, qd, t) - controller.compute(q, qd, t)).max())
        wall = min(walls[method])
        results[method] = {
            "compiled_us": stats(np.array(fast_times[method])),
            "casadi_function_us": stats(np.array(slow_times[method])),
            "speedup_median": 0.0,
            "inputs_agree_max_abs": agree,
            "simulation_wall_s": wall,
            "simulated_s": float(runs[method].t[-1]),
            "real_time_factor": float(runs[method].t[-1] / wall),
            "retained_bytes_per_control_step": retained_bytes(lambda c=controller, s=states[100]: c.compute(*s),
                                                              2000),
            "retained_bytes_per_plant_step": retained_bytes(
                lambda x=x, u=reference.u[0], table=table: plant.advance(x, u, h, table, 0, 1), 2000),
            "paper_matlab_mean_us": PAPER_MATLAB_US.get(method),
            "goal_median_us": GOALS_US.get(method),
        }
        r = results[method]
        r["speedup_median"] = r["casadi_function_us"]["median"] / r["compiled_us"]["median"]
    return results, states


def bench_plant_step(crane, q0: np.ndarray, u0: np.ndarray, passes: int = 15, calls: int = 2000) -> dict:
    """The plant's step with the spec's numbers folded in (a plant without plant_params) against the
    parametric one (a plant given one of them at the spec's own value), the same library and state."""
    from ..sim.plant import Plant

    sim = crane.spec.simulation
    values = crane.plant_parameters()
    mass = next(name for name in values if name.endswith(".mass"))
    plants = {"folded": Plant(crane.model, crane.path, sim.baumgarte_zeta, sim.baumgarte_omega),
              "parametric": Plant(crane.model, crane.path, sim.baumgarte_zeta, sim.baumgarte_omega,
                                  {mass: values[mass]})}
    best = {}
    for plant in plants.values():
        plant.probe(plant.initial_state(q0), u0, 0.0)  # loads state, input and stage signals
    clock = time.perf_counter
    for _ in range(passes):  # interleaved: a slow stretch of the machine hits both alike
        for name, plant in plants.items():
            call = plant._step.call
            t0 = clock()
            for _ in range(calls):
                call()
            best[name] = min(best.get(name, np.inf), (clock() - t0) / calls)
    return {"folded_us": 1e6 * best["folded"], "parametric_us": 1e6 * best["parametric"],
            "ratio": best["parametric"] / best["folded"], "passes": passes}


def bench_limits(spec_path: Path, methods: list[str], repeats: int) -> dict:
    """Control step on a crane's own scenario with its limits, without, and saturated at every step."""
    from ..api.crane import Crane
    from ..control.controllers import make_controller, unbounded
    from ..sim.simulation import setup_default, simulate

    crane = Crane.from_toml(spec_path)
    spec, model, path, gains, start = crane.spec, crane.model, crane.path, crane.gains(), crane.equilibrium()
    rate, h = spec.controller.rate_hz, spec.simulation.step
    reference = simulate(model, path, make_controller(methods[0], model, path, gains), setup_default(model, path),
                         start.q, path.duration, rate, h)
    states = list(zip(reference.q, reference.qd, reference.t, strict=True))
    lower, upper, preferred = spec.input_limits()
    winches = np.isfinite(upper) & (lower >= 0)
    saturating = upper.copy()
    saturating[winches] = 0.99 * start.inputs[winches]
    variants = {"spec limits": None, "no limits": unbounded(spec), "saturated": (lower, saturating, preferred)}
    controllers = {(m, v): make_controller(m, model, path, gains, limits=lim)
                   for m in methods for v, lim in variants.items()}
    times = {key: [] for key in controllers}
    for _ in range(repeats):  # interleaved passes
        for key, controller in controllers.items():
            times[key].append(time_steps(controller, states, 1)[0])
    out = {"spec": spec.name, "variants": {"saturated": "every winch's max at 0.99 x its static tension"},
           "methods": {}}
    for m in methods:
        row = {}
        for v in variants:
            controller = controllers[(m, v)]
            row[v] = {"control_step_us": stats(np.array(times[(m, v)])),
                      "qp_solves_per_step": controller.limits.qp_solves / (repeats * len(states))}
        row["extra_us_with_limits"] = (row["spec limits"]["control_step_us"]["median"]
                                       - row["no limits"]["control_step_us"]["median"])
        row["extra_us_saturated"] = (row["saturated"]["control_step_us"]["median"]
                                     - row["no limits"]["control_step_us"]["median"])
        out["methods"][m] = row
    return out


def format_limits_table(limits: dict) -> str:
    head = (f"{'method':<12} {'spec limits':>11} {'no limits':>9} {'saturated':>9} {'QP/step':>7} "
            f"{'extra (limits)':>14} {'extra (saturated)':>17}")
    lines = [f"input limits on {limits['spec']} (control step median, us; saturated: "
             f"{limits['variants']['saturated']}):", head, "-" * len(head)]
    for m, r in limits["methods"].items():
        lines.append(
            f"{m:<12} {r['spec limits']['control_step_us']['median']:11.1f} "
            f"{r['no limits']['control_step_us']['median']:9.1f} {r['saturated']['control_step_us']['median']:9.1f} "
            f"{r['saturated']['qp_solves_per_step']:7.2f} {r['extra_us_with_limits']:14.1f} "
            f"{r['extra_us_saturated']:17.1f}"
        )
    return "\n".join(lines)


def _processor() -> str:
    """The CPU's model name (platform.processor() is empty on Linux; /proc/cpuinfo says it)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name":
                return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


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
