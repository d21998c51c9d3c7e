"""The robustness Monte Carlo's driver (`acroboter robustness`, docs/robustness.md): N plants drawn around the spec's
physical parameters (acroboter.studies.robustness_grid), each run by every method with the PD law and with integral
action, through the library (`Crane.simulate`) on a dask cluster or in this process; the worst sample re-run.
What it writes and how it is summarised is acroboter.cli.robustness's and acroboter.report.robustness_report's.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from .grid import open_client, prepare, run_cases, worker_count
from .robustness_grid import DEFAULT_METHODS, command, crashed_rows, draw_sample, recommended_ki, run_sample


@dataclass
class RobustnessResult:
    """A robustness study's runs: one row per sample, method and ki, the samples drawn, the wall time, the workers,
    the ki of the integral-action rows, the spec; `summary` and `files` filled in by whoever reports it."""

    rows: list[dict]
    samples: list
    wall_s: float
    workers: int
    ki: float
    spec: object = None
    summary: dict = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)


def run_study(spec_path: Path, *, samples: int, seed: int, duration: float, ranges: dict,
              methods: tuple[str, ...] = DEFAULT_METHODS, ki: float | None = None, workers: int = 2,
              scheduler: str | None = None, connect_timeout: float = 10.0, progress: bool = False, sensing=None,
              fast: bool = False) -> RobustnessResult:
    """Build once here, check ki and the sensing against the spec, draw `samples` plants within `ranges`, and run
    each (every method, ki = 0 and ki) on the cluster, or in this process with workers = 0. GridError when it
    cannot run at all; ValueError for a bad ki or sensing."""
    from tqdm import tqdm

    spec = prepare(spec_path, duration)  # builds the library here if missing: the tasks only load it
    ki = _checked_ki(spec, ki)
    _check_sensing(spec, sensing, duration)
    prebuild(spec, methods, sensing, fast)
    drawn = [draw_sample(spec, seed, i, ranges) for i in range(samples)]
    task = functools.partial(run_sample, Path(spec_path).read_text(encoding="utf-8"), str(spec_path),
                             duration=duration, methods=tuple(methods), kis=(0.0, ki), sensing=sensing, fast=fast)
    t0 = time.perf_counter()
    with tqdm(total=samples, unit="sample", desc="robustness", file=sys.stderr, disable=not progress,
              smoothing=0.0) as bar:
        def done(_sample, _rows):
            bar.update(1)

        if scheduler or workers > 0:
            with open_client(scheduler, workers, connect_timeout) as client:
                n_workers = worker_count(client) if scheduler else workers
                per_sample = run_cases(task, drawn, client, name="robustness", on_done=done, on_error=crashed_rows)
        else:
            n_workers = 0
            per_sample = run_cases(task, drawn, None, on_done=done, on_error=crashed_rows)
    wall = time.perf_counter() - t0
    rows = [row for block in per_sample for row in block]
    return RobustnessResult(rows, drawn, wall, n_workers, ki, spec)


def _checked_ki(spec, ki: float | None) -> float:
    """ki of the integral-action rows: docs/integral_action.md's choice by default, else checked (Routh–Hurwitz)."""
    from ..model.ranges import INTEGRAL_GAIN
    from ..model.spec import integral_gain_problem

    kp, kd = spec.controller.kp, spec.controller.kd
    ki = recommended_ki(kp, kd) if ki is None else INTEGRAL_GAIN.check(ki, "--ki")  # a RangeError, a ValueError
    if (problem := integral_gain_problem(kp, kd, ki)) is not None:
        raise ValueError(f"--ki: {problem}")
    return ki


def _check_sensing(spec, sensing, duration: float) -> None:
    """The --sensing-* overrides against the spec, before any task: a bad group or value is bad input."""
    if sensing is None:
        return
    from ..model.ranges import delay_problem
    from ..model.spec import SpecError
    from ..sim.sensing import resolve

    try:
        chosen = resolve(spec, sensing, source="--sensing-*")
    except SpecError as err:
        raise ValueError(str(err)) from None
    if chosen is not None and (problem := delay_problem(chosen.delay_periods, spec.controller.rate_hz,
                                                        duration)) is not None:
        raise ValueError(f"--sensing-delay: {problem}")


def prebuild(spec, methods, sensing, fast: bool) -> None:
    """What the runs load from the cache, built here before any task, so that the workers only load it as they load
    the model's library: the plant's substep loop, and with `fast` the fast steps of `methods` and the compiled
    estimator of the sensing the runs use (--sensing-*, else the spec's section). A method the fast path cannot have
    runs on its reference path in the workers too (make_controller says why)."""
    from ..control.controllers import Gains
    from ..runtime.cache import load_model
    from ..runtime.compile_library import BuildError
    from ..runtime.fast_library import FastPathUnavailable, load_fast_estimator, load_fast_step
    from ..runtime.plant_loop import load_plant_loop
    from ..sim.sensing import is_ideal, resolve

    model = load_model(spec)
    try:
        load_plant_loop(model.cache_root)
    except BuildError:
        pass  # each worker's plants then run Python's loop (the same numbers) and say so once
    if not fast:
        return
    gains = Gains.from_spec(spec)
    for method in methods:
        try:
            load_fast_step(model, method, gains)
        except FastPathUnavailable:
            continue
    chosen = resolve(spec, sensing, source="--sensing-*")  # None: the spec's section, as Crane.simulate
    if chosen is not None and not is_ideal(spec, model.layout, chosen):
        load_fast_estimator(model, chosen)


def rerun_worst(spec_path, result: RobustnessResult, duration, methods, sensing, fast: bool = False) -> dict:
    """The sample with the largest max position error of any of its rows, re-run here, every method and ki."""
    from ..api.crane import Crane

    def badness(r):
        return math.inf if r.get("status") != "ok" else r["max_position_error_mm"]

    index = max((r for r in result.rows if r["method"] is not None), key=badness)["sample"]
    sample = result.samples[index]
    crane = Crane.from_toml(spec_path)
    extra = {} if sensing is None else {"sensing": sensing}
    results: dict = {}
    for m in methods:
        for ki in (0.0, result.ki):
            try:
                results.setdefault(m, {})[ki] = crane.simulate(m, duration=duration, plant_params=sample.params,
                                                               ki=ki, fast=fast, **extra)
            except Exception:  # noqa: BLE001 - a run that fails here failed in the study too (its row says how)
                continue
    return {"sample": index, "mass_error": sample.mass_error, "tracked_mass_error": sample.tracked_mass_error,
            "results": results, "command": command(spec_path, sample, duration, sensing=sensing, fast=fast)}


