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
closed loop's real-time factor with and without sensing; the Monte Carlo throughput. The measuring is
acroboter.studies.scenario_timings's and acroboter.studies.step_timings's; this module parses, calls, prints and
writes bench.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

from ..model.ranges import CASADI_STATES, MC_SAMPLES, REPEATS
from ..model.spec import MAX_ITERATIONS
from ..process.locations import example_spec
from ..report.paper import PAPER_MATLAB_US
from ..studies.scenario_timings import (
    TimingError,
    bench_limits,
    bench_plant_step,
    closed_loops,
    runnable_controllers,
    step_results,
    time_model_terms,
)
from .entry import guarded, ranged, spec_file
from .outputs import ResultsFolder, out_path, results_folder

GOALS_US = {"mlm": 20.0, "penalty": 15.0, "iterative-5": 20.0}
MIN_INSTANTS = 101  # the allocation check steps from instant 100 of the scenario


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
    parser.add_argument("--limits-spec", type=spec_file, default=example_spec("acroboter_4cable"),
                        help="crane on which the cost of input limits is timed: a spec file or an example's name "
                             "(default: %(default)s)")
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
        controllers, refused = runnable_controllers(crane, methods, start)
        for m, why in refused.items():  # a method that cannot handle this spec is left out, with its reason
            print(f"  {m} left out: {why}", file=sys.stderr)
        if not controllers:
            raise TimingError("no method can run on this spec", 3)
        methods = list(controllers)
        runs, walls = closed_loops(crane, methods)
    except TimingError as err:
        print(f"error: {err}", file=sys.stderr)
        return err.status
    results, states = step_results(crane, controllers, runs, walls, start, args.repeats, args.casadi_states)
    for method, r in results.items():  # the paper's figures and the goals beside the measured ones
        r.update(paper_matlab_mean_us=PAPER_MATLAB_US.get(method), goal_median_us=GOALS_US.get(method))
    print(format_table(results))
    print(f"all model terms at one state (model_terms, one ctypes call): median {model_terms_us['median']:.2f} us, "
          f"p99 {model_terms_us['p99']:.2f} us")
    try:
        limits = bench_limits(args.limits_spec, methods, args.repeats)
    except (SpecError, StaleModelError, SimulationError, SingularSystemError) as err:
        print(f"error: cannot time the input limits on {args.limits_spec}: {err}", file=sys.stderr)
        return 3
    print(format_limits_table(limits))
    from ..studies.step_timings import bench_loops, bench_monte_carlo, bench_steps

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
        raise TimingError(str(err), 2) from None
    path, rate = crane.path, crane.spec.controller.rate_hz
    if path.duration * rate < MIN_INSTANTS:
        raise TimingError(f"the scenario of {crane.spec.name} has {path.duration * rate:.0f} control instants, the "
                          f"benchmark needs at least {MIN_INSTANTS}: lengthen the path (or lower path.mean_speed)", 2)
    return crane, crane.equilibrium()


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


def format_steps(steps: dict, loops: dict, mc: dict | None) -> str:
    head = (f"{'method':<12} {'ref p50':>7} {'p99':>6} {'max':>6} {'fast p50':>8} {'p99':>6} {'max':>6} "
            f"{'C p50':>6} {'p99':>6} {'max':>6} {'fast/C':>6} {'ref/C':>6} {'ref/fast':>8} {'RTF ref':>7} "
            f"{'fast':>6} {'+sens ref':>9} {'fast':>6}")
    lines = ["control step (us; the quietest of the interleaved passes) and the 55 s closed loop's real-time factor:",
             head, "-" * len(head)]
    for m, r in steps["methods"].items():
        a, b, c, rtf = r["reference"], r["fast"], r["c"], loops.get(m, {})
        lines.append(
            f"{m:<12} {a['p50']:7.2f} {a['p99']:6.1f} {a['max']:6.0f} {b['p50']:8.2f} {b['p99']:6.1f} {b['max']:6.0f} "
            f"{c['p50']:6.2f} {c['p99']:6.1f} {c['max']:6.0f} {r['ratio_fast_to_c']:6.2f} "
            f"{r['ratio_reference_to_c']:6.2f} {r['ratio_reference_to_fast']:8.2f} "
            f"{rtf.get('rtf_reference', float('nan')):7.0f} {rtf.get('rtf_fast', float('nan')):6.0f} "
            f"{rtf.get('rtf_reference_sensing', float('nan')):9.0f} {rtf.get('rtf_fast_sensing', float('nan')):6.0f}")
    est, flat = steps["estimator"], steps["path_evaluation"]
    lines.append(f"path evaluation in Python (the reference step's; the fast step evaluates the spec's path in its "
                 f"C; neither is in the exported C step's timing): p50 {flat['p50']:.2f} us, "
                 f"p99 {flat['p99']:.1f} us")
    if est is not None:
        lines.append(f"estimator (measurement, projection, alpha-beta filter), Python: p50 {est['p50']:.2f} us, p99 "
                     f"{est['p99']:.1f} us, max {est['max']:.0f} us")
    if (fast := steps.get("estimator_fast")) is not None:
        lines.append(f"estimator, compiled (the fast path's): p50 {fast['p50']:.2f} us, p99 {fast['p99']:.1f} us, "
                     f"max {fast['max']:.0f} us; fast step + estimator / C step: "
                     + ", ".join(f"{m} {r['ratio_fast_with_estimator_to_c']:.2f}" for m, r in steps["methods"].items()))
    with_estimator = [(m, r) for m, r in steps["methods"].items() if "c_estimator" in r]
    if with_estimator and (fast := steps.get("estimator_fast")) is not None:
        lines.append("exported stateful controller (estimator, integral state and step in one C call) p50 / p99 / "
                     "max us, and (fast step + compiled estimator) / it: "
                     + "; ".join(f"{m} {r['c_estimator']['p50']:.2f} / {r['c_estimator']['p99']:.1f} / "
                                 f"{r['c_estimator']['max']:.0f}, "
                                 f"{r['ratio_fast_with_estimator_to_c_with_estimator']:.2f}"
                                 for m, r in with_estimator))
    if loops:
        lines.append("the plant alone (its substeps, events and energy check over the scenario, a run's inputs "
                     f"replayed; best of the same passes): RTF {next(iter(loops.values()))['rtf_plant_alone']:.0f}")
    if mc is not None:
        lines.append(
            f"Monte Carlo ({mc['samples']} plants x {len(mc['methods'])} methods x k_I {{0, "
            f"{mc['kis'][1]:g}}}, {mc['duration_s']:g} s, one process): reference {mc['runs_per_s_reference']:.2f} "
            f"runs/s, fast {mc['runs_per_s_fast']:.2f} runs/s; the default study ({mc['default_study_runs']} runs) on "
            f"2 cores: ~{mc['default_study_estimate_s_reference_2_cores']:.0f} s reference, "
            f"~{mc['default_study_estimate_s_fast_2_cores']:.0f} s fast")
    return "\n".join(lines)
