"""What `acroboter bench` times on a crane's scenario (acroboter.cli.bench writes and prints it): the control step
of each method on the scenario's states, compiled against the casadi.Function path, with the bytes a step keeps;
the whole closed loop's real-time factor; the model terms in one call; the plant's step folded and parametric;
what input limits cost. Each figure comes from interleaved passes in one run (a slow stretch of a shared machine
hits all alike); none is asserted on: they are measurements with their date and machine.
"""

from __future__ import annotations

import time
import tracemalloc
from pathlib import Path

import numpy as np


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


class TimingError(Exception):
    """The benchmark cannot run as asked: the text (printed as 'error: …') and the exit status."""

    def __init__(self, text: str, status: int):
        super().__init__(text)
        self.status = status


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


def runnable_controllers(crane, methods: list[str], start) -> tuple[dict, dict]:
    """({method: controller} of the methods that run on this crane, {method: why not} of those that cannot)."""
    from ..control.controllers import SingularSystemError, make_controller
    from ..control.recovery import RecoveryError

    controllers, refused = {}, {}
    for m in methods:
        try:
            controllers[m] = make_controller(m, crane.model, crane.path, crane.gains())
            controllers[m].compute(start.q, np.zeros(crane.layout.n), 0.0)
        except (SingularSystemError, RecoveryError) as err:
            controllers.pop(m, None)
            refused[m] = str(err)
    return controllers, refused


def closed_loops(crane, methods) -> tuple[dict, dict]:
    """Whole closed loops through the library (`crane.simulate`), best of 3 (interleaved, so a slow stretch of the
    machine hits all alike): {method: RunResult} and {method: [wall s]}."""
    runs, walls = {}, {m: [] for m in methods}
    for _ in range(3):
        for m in methods:
            result = crane.simulate(m)
            if result.diverged_at is not None:
                raise TimingError("the scenario does not run to the end, nothing to time: "
                                  f"{m} diverged at t = {result.diverged_at:.2f} s: {result.run.divergence}", 3)
            runs[m] = result.run
            walls[m].append(result.run.sim_wall_s)
    return runs, walls


def step_results(crane, controllers: dict, runs: dict, walls: dict, start, repeats: int,
                 casadi_states: int) -> tuple[dict, list]:
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
    stride = max(1, len(states) // casadi_states)
    fast_times = {m: [] for m in methods}
    slow_times = {m: [] for m in methods}
    for r in range(repeats):  # interleaved passes, as in bench_steps
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
