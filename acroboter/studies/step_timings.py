"""`acroboter bench`'s comparison of the control step's three forms, and the loop's throughput (issue 23 item 3).

Per method, in the same interleaved passes over the states of the scenario (one pass = every state, each call
timed on its own with time.perf_counter):
  - the Python step on its reference path (per-term generated call, LAPACK through scipy) and on its fast path
    (acroboter.control.fast_path: one compiled function, the spec's path evaluated in it), both
    `controller.compute(q, q̇, t)` with the path's signals evaluated at t;
  - the exported C step (acroboter.codegen.export_step, as `acroboter export-step` writes it: gains baked in),
    compiled here (-O2 -fPIC, no fast-math) and called in-process through ctypes, the signals already loaded;
  - the estimator of the sensing (acroboter.sim.sensing: measurement, projection, α-β filter), on the same states;
their p50, p99 and maximum (µs; the pass with the lowest median, the quietest of a shared machine), and the
ratios of the medians. Then the whole closed loop's real-time factor (simulated ÷ wall seconds), reference and
fast, without and with sensing, and the Monte Carlo throughput (runs per second in one process) on a small sample
of the default robustness study (its plants, 20 s runs, every method with and without integral action).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ..runtime.exported import compile_shared, load_exported_controller

# Sensing for the estimator's cost and the loop with sensing, where the spec has no [sensing] section: trackers
# with 0.2 mm noise and one period of delay (the Monte Carlo's sensing case, docs/sensing.md).
DEFAULT_SENSING = {"noise": {"positions": 2e-4}, "delay_periods": 1, "seed": 1}
MC_DURATION_S = 20.0


def percentiles(seconds: list[np.ndarray]) -> dict:
    """p50, p99, max (µs) of the quietest pass (lowest median), and the median over every pass."""
    us = 1e6 * np.array(seconds)
    best = us[int(np.argmin(np.median(us, axis=1)))]
    return {"p50": float(np.median(best)), "p99": float(np.percentile(best, 99)), "max": float(best.max()),
            "passes": int(us.shape[0]), "p50_all_passes": float(np.median(us))}


def exported_step(crane, method: str, gains, folder: Path):
    """The exported C step of `method` compiled into `folder` and bound to the model's input buffers."""
    from ..codegen.export_step import build_step, write_step
    from ..runtime.compiled import BoundFunction

    export = build_step(crane.spec, method, gains)
    (source, _) = write_step(export, folder)
    lib = compile_shared([source], folder / f"lib{export.name}.so", f"the exported step {source.name}")
    model = crane.model
    return BoundFunction(lib, export.name, [model.q, model.qd, model.s, model.sd, model.sdd],
                         [("u", [crane.layout.l, 1])])


def exported_controller(crane, method: str, gains, sensing, folder: Path):
    """The stateful exported controller of `method` with the estimator of `sensing` (acroboter.codegen.controller_c,
    as `acroboter export-step --stateful` writes it) compiled into `folder` and bound (runtime.exported)."""
    from ..api.stateful import controller_constants
    from ..codegen.controller_c import build_controller, write_controller

    export = build_controller(crane.spec, method, gains, sensing, **controller_constants(crane))
    write_controller(export, folder)
    return load_exported_controller(folder, export.name, crane.layout.l, crane.layout.n_signals)


def bench_steps(crane, methods: list[str], states, repeats: int) -> dict:
    """Interleaved passes: per method the reference, fast and exported C steps, and the estimator, timed."""
    bench = _StepBench(crane, methods, states)
    with tempfile.TemporaryDirectory(prefix="acroboter-bench-") as tmp:
        bench.compile(Path(tmp))
        for _ in range(repeats):
            for m in methods:
                bench.time_python(m)
                bench.time_exported(m)
                bench.time_stateful(m)
            bench.time_path()
            bench.time_estimators()
    return bench.summary()


class _StepBench:
    """The steps `bench_steps` times, over the same states, each call timed on its own (`times[(what, kind)]`:
    one row of seconds per pass)."""

    def __init__(self, crane, methods: list[str], states):
        from ..control.controllers import make_controller
        from ..sim.fast_estimator import make_estimator

        self.crane, self.methods, self.states = crane, methods, states
        self.model, self.path, self.gains = crane.model, crane.path, crane.gains()
        model, path, gains = self.model, self.path, self.gains
        self.reference = {m: make_controller(m, model, path, gains) for m in methods}
        self.fast = {m: make_controller(m, model, path, gains, fast=True) for m in methods}
        self.sensing = crane.sensing(None) or crane.sensing(DEFAULT_SENSING)
        self.estimators = {"estimator": make_estimator(model, path, self.sensing),
                           "estimator_fast": make_estimator(model, path, self.sensing, fast=True)}
        self.signals = [path.flat(t).copy() for _, _, t in states]
        self.times = {(m, kind): [] for m in methods for kind in ("reference", "fast", "c", "c_estimator")}
        self.times[("estimator", "estimator")], self.times[("estimator", "estimator_fast")] = [], []
        self.times[("path", "path")] = []  # the path's signals at t: part of both Python steps, not of the C step's
        # The measurements the stateful C controller reads: the Python sensor's (noise, quantisation; one per state)
        self.sensor = sensor = self.estimators["estimator"]
        self.measurements = []
        if sensor is not None:
            sensor.reset(states[0][0])
            for q, _, _ in states:
                y = np.zeros(sensor.index.size)
                sensor._sample(q, y)
                self.measurements.append(y)
        self.refused: dict[str, str] = {}  # method -> why it has no stateful exported controller
        self.step_codes: dict[str, dict[int, int]] = {}  # method -> the stateful controller's return codes, counted
        self.start_q = crane.equilibrium().q
        self.exported: dict = {}
        self.stateful: dict = {}

    def compile(self, folder: Path) -> None:
        """The exported C steps, and with sensing the stateful exported controllers, compiled into `folder`."""
        from ..codegen.step_graph import ExportError

        self.exported = {m: exported_step(self.crane, m, self.gains, folder / m) for m in self.methods}
        for m in self.methods if self.sensor is not None else ():
            try:
                self.stateful[m] = exported_controller(self.crane, m, self.gains, self.sensing,
                                                       folder / f"{m}-controller")
            except ExportError as err:  # e.g. MLM with internal forces has no q̈ for the estimator: said, not timed
                self.refused[m] = str(err)

    def time_python(self, m: str) -> None:
        clock = time.perf_counter
        for kind, controller in (("reference", self.reference[m]), ("fast", self.fast[m])):
            row, compute = np.empty(len(self.states)), controller.compute
            for i, (q, qd, t) in enumerate(self.states):
                t0 = clock()
                compute(q, qd, t)
                row[i] = clock() - t0
            self.times[(m, kind)].append(row)

    def time_exported(self, m: str) -> None:
        """The exported C step, its inputs loaded before each timed call."""
        clock, model, signals = time.perf_counter, self.model, self.signals
        row, call, q_buf, qd_buf, sig_buf = np.empty(len(self.states)), self.exported[m].call, model.q, model.qd, \
            model.signals
        for i, (q, qd, _) in enumerate(self.states):
            q_buf[:], qd_buf[:], sig_buf[:] = q, qd, signals[i]
            t0 = clock()
            call()
            row[i] = clock() - t0
        self.times[(m, "c")].append(row)

    def time_stateful(self, m: str) -> None:
        """The stateful exported controller: estimator and step, one C call, from the static start (the states need
        not be a run's: its codes are counted, not refused)."""
        if m not in self.stateful:
            return
        clock, controller = time.perf_counter, self.stateful[m]
        row = np.empty(len(self.states))
        if controller.init(self.start_q, controller.path(0.0).copy()) != 0:
            raise RuntimeError(f"the exported {m} controller refused the static start")
        step, codes = controller.step, self.step_codes.setdefault(m, {})
        signal_arrays = [np.array(sig) for sig in self.signals]
        for i, (_, _, t) in enumerate(self.states):
            y, sig = self.measurements[i], signal_arrays[i]
            t0 = clock()
            rc = step(y, t, sig)
            row[i] = clock() - t0
            codes[rc] = codes.get(rc, 0) + 1
        self.times[(m, "c_estimator")].append(row)

    def time_path(self) -> None:
        clock, row, flat = time.perf_counter, np.empty(len(self.states)), self.path.flat
        for i, (_, _, t) in enumerate(self.states):
            t0 = clock()
            flat(t)
            row[i] = clock() - t0
        self.times[("path", "path")].append(row)

    def time_estimators(self) -> None:
        clock, states = time.perf_counter, self.states
        for kind, estimator in self.estimators.items():
            if estimator is None:
                continue
            row, rest = np.empty(len(states)), np.zeros(states[0][0].size)
            estimator.reset(states[0][0])
            for i, (q, _, t) in enumerate(states):
                t0 = clock()
                estimator.estimate(q, t)
                row[i] = clock() - t0
                estimator.applied(rest)
            self.times[("estimator", kind)].append(row)

    def summary(self) -> dict:
        """Percentiles per method and kind, and the ratios of the medians."""
        times, out = self.times, {"methods": {}, "fast_path": {}}
        for m in self.methods:
            r = {kind: percentiles(times[(m, kind)]) for kind in ("reference", "fast", "c")}
            r["ratio_fast_to_c"] = r["fast"]["p50"] / r["c"]["p50"]
            r["ratio_reference_to_c"] = r["reference"]["p50"] / r["c"]["p50"]
            r["ratio_reference_to_fast"] = r["reference"]["p50"] / r["fast"]["p50"]
            out["methods"][m] = r
            out["fast_path"][m] = getattr(self.fast[m], "fast_refusal", None) or "compiled step"
        est, est_fast = times[("estimator", "estimator")], times[("estimator", "estimator_fast")]
        out["estimator"] = percentiles(est) if est else None
        out["estimator_fast"] = percentiles(est_fast) if est_fast else None
        if est and est_fast:
            out["estimator_ratio_reference_to_fast"] = out["estimator"]["p50"] / out["estimator_fast"]["p50"]
        for m in self.methods:
            self._with_estimator(out, m)
        out["path_evaluation"] = percentiles(times[("path", "path")])
        out["sensing"] = "the spec's [sensing]" if self.crane.sensing(None) is not None else f"{DEFAULT_SENSING}"
        return out

    def _with_estimator(self, out: dict, m: str) -> None:
        """The issue's target: the fast step with the estimator against the C step with the estimator."""
        r, fast_estimator = out["methods"][m], out["estimator_fast"]
        if self.times[(m, "c_estimator")]:
            r["c_estimator"] = percentiles(self.times[(m, "c_estimator")])
            # its return codes over all passes (0: the sample accepted; 4, 5: rejected, the states not a run's)
            r["c_estimator_codes"] = {str(code): count for code, count in sorted(self.step_codes[m].items())}
        elif m in self.refused:
            r["c_estimator_refused"] = self.refused[m]
        if fast_estimator is not None:
            r["ratio_fast_with_estimator_to_c"] = (r["fast"]["p50"] + fast_estimator["p50"]) / r["c"]["p50"]
            if "c_estimator" in r:
                r["ratio_fast_with_estimator_to_c_with_estimator"] = (
                    (r["fast"]["p50"] + fast_estimator["p50"]) / r["c_estimator"]["p50"])


def bench_loops(crane, methods: list[str], passes: int = 2) -> dict:
    """The whole scenario's closed loop per method: real-time factor, reference and fast, without and with sensing
    (the best of `passes` interleaved runs)."""
    sensing = crane.sensing(None) or crane.sensing(DEFAULT_SENSING)
    out = {m: {} for m in methods}
    alone = 0.0
    for _ in range(passes):
        for m in methods:
            row = out[m]
            for fast in (False, True):
                for label, chosen in (("", False), ("_sensing", sensing)):
                    result = crane.simulate(m, fast=fast, sensing=chosen)
                    key = f"rtf_{'fast' if fast else 'reference'}{label}"
                    row[key] = max(row.get(key, 0.0), float(result.run.t[-1] / result.run.sim_wall_s))
            _, wall = replay_plant(crane, result.run.u)
            alone = max(alone, float(result.run.t[-1]) / wall)
    for row in out.values():  # the same for every method: the plant's share of the loop, its ceiling
        row["rtf_plant_alone"] = alone
    return out


def replay_plant(crane, inputs: np.ndarray) -> tuple[np.ndarray, float]:
    """The plant alone through a run's recorded inputs from the same start: its control periods (RK4 substeps in C,
    the events, the energy check), no controller, no records. (Its final state, the wall seconds.) The same plant,
    start and inputs give that run's states to the bit, so the time is the plant's share of the loop."""
    from ..sim.simulation import STAGE_CHUNK, setup_default

    spec, model = crane.spec, crane.model
    period = 1.0 / spec.controller.rate_hz
    substeps = round(period / spec.simulation.step)
    h = period / substeps
    plant = setup_default(model, crane.path)
    x = plant.initial_state(crane.equilibrium().q)
    steps = len(inputs) - 1
    t0 = time.perf_counter()
    for start in range(0, steps, STAGE_CHUNK):  # simulate's chunks: the same tables, so the same event times
        count = min(STAGE_CHUNK, steps - start)
        table = plant.stage_rows(h, start * substeps, count * substeps)
        for k in range(count):
            plant.advance(x, inputs[start + k], h, table, k * substeps, substeps)
    return x, time.perf_counter() - t0


def bench_monte_carlo(crane, methods: list[str], samples: int) -> dict:
    """Runs per second in one process on `samples` plants of the default robustness study (20 s, every method,
    k_I 0 and the study's recommended one), reference and fast; and what that makes of the default study."""
    from ..studies.robustness_grid import default_ranges, draw_sample, recommended_ki

    draws = [draw_sample(crane.spec, 0, i, default_ranges()) for i in range(samples)]
    kis = (0.0, recommended_ki(crane.spec.controller.kp, crane.spec.controller.kd))
    out = {"samples": samples, "duration_s": MC_DURATION_S, "methods": list(methods), "kis": list(kis)}
    for fast in (False, True):
        runs, t0 = 0, time.perf_counter()
        for sample in draws:
            for m in methods:
                for ki in kis:
                    crane.simulate(m, duration=MC_DURATION_S, plant_params=sample.params, ki=ki, fast=fast)
                    runs += 1
        wall = time.perf_counter() - t0
        out[f"runs_per_s_{'fast' if fast else 'reference'}"] = runs / wall
    # The default study: 200 samples x 5 methods x 2 (k_I) runs of 20 s, on two worker processes.
    out["default_study_runs"] = 200 * 5 * 2
    for kind in ("reference", "fast"):
        out[f"default_study_estimate_s_{kind}_2_cores"] = out["default_study_runs"] / out[f"runs_per_s_{kind}"] / 2
    return out
