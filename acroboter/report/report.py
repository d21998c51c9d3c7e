"""What a run writes besides the CSVs (Result.to_csv) and figures (report/figures.py): summary.json, the table."""

from __future__ import annotations

import json
from pathlib import Path

from ..sim.records import RunResult, Scenario
from .paper import PAPER_MATLAB_US


def write_summary(path: Path, spec_name: str, summaries: dict, duration: float, warnings: list[str],
                  extra: dict | None = None) -> None:
    doc = {"spec": spec_name, "duration_s": duration, "methods": summaries, "warnings": warnings, **(extra or {})}
    path.write_text(json.dumps(doc, indent=2) + "\n")


def format_table(summaries: dict, paper: bool = True) -> str:
    """The run's table, one row per method.

    `paper`: the run is the paper's crane (the shipped 'acroboter' example), so a MATLAB column gives
    the paper's mean control-step time per method and a last line the paper's bounds. For any other
    crane (paper=False) both are left out: they were measured on the paper's crane, not this one."""
    head = (f"{'method':<13} {'max pos':>8} {'rms pos':>8} {'max yaw':>8} {'max tilt':>8} {'max |phi|':>9} "
            f"{'tension range':>15} {'step median':>11} {'step mean':>9} {'p99':>7}")
    units = (f"{'':<13} {'mm':>8} {'mm':>8} {'deg':>8} {'deg':>8} {'':>9} {'N':>15} "
             f"{'us':>11} {'us':>9} {'us':>7}")
    if paper:
        head += f" {'MATLAB':>7}"
        units += f" {'us':>7}"
    lines = [head, units, "-" * len(head)]
    for method, s in summaries.items():
        if "error" in s:
            lines.append(f"{method:<13} cannot run: {s['error'][:90]}...")
            continue
        yaw = f"{s['max_yaw_error_deg']:8.4f}" if s["max_yaw_error_deg"] is not None else f"{'-':>8}"
        tension = (f"{s['min_winch_tension_N']:6.2f}..{s['max_winch_tension_N']:<6.2f}"
                   if s.get("min_winch_tension_N") is not None else "-")
        matlab = PAPER_MATLAB_US.get(method)
        matlab_s = (f" {matlab:7.1f}" if matlab else f" {'-':>7}") if paper else ""
        step = s["control_step_us"]
        pos = (f"{s['max_position_error_mm']:8.4f} {s['rms_position_error_mm']:8.4f}"
               if s["max_position_error_mm"] is not None else f"{'unbounded':>17}")
        lines.append(
            f"{method:<13} {pos} {yaw} "
            f"{s['max_tilt_deg']:8.4f} {s['max_constraint_violation']:9.1e} {tension:>15} "
            f"{step['median']:11.1f} {step['mean']:9.1f} {step['p99']:7.1f}{matlab_s}"
        )
    for method, s in summaries.items():
        if s.get("diverged_at_s") is not None:
            lines.append(f"{method}: diverged at t = {s['diverged_at_s']:.2f} s; the figures above stop there")
    if paper:
        lines.append("MATLAB: the paper's mean control-step time (R2019b, i7-8700). Paper bounds: 5.3 mm, 1.1 deg.")
    return "\n".join(lines)


def write_figures(out: Path, results: dict[str, RunResult], scenario: Scenario, summaries: dict,
                  input_names: list[str], servo_names: list[str], input_limits=None,
                  paper: bool = True) -> list[Path]:
    """The run's figures, written into `out`; returns their paths (acroboter.report.figures.FIGURE_NAMES).

    `input_names`: the inputs' y-labels with units; `servo_names`: the servo-constraints' names;
    `input_limits` (min, max) per input are drawn on the inputs' panels; `paper=False` (a crane
    that is not the paper's) leaves the paper's MATLAB times out of control_step_time.png.
    A thin alias of acroboter.report.figures.write_figures (imported here on use: matplotlib loads only then)."""
    from .figures import write_figures as write

    return write(out, results, scenario, summaries, input_names, servo_names, input_limits, paper)
