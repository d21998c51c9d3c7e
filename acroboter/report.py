"""What a run writes: the per-method CSV time series, summary.json, the table and the figures."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from .simulation import RunResult, Scenario

# Mean control-step time in MATLAB R2019b on an i7-8700 (paper, section 4), in microseconds.
PAPER_MATLAB_US = {"mlm": 309.06, "penalty": 304.78, "iterative-3": 384.28, "iterative-4": 385.41,
                   "iterative-5": 410.62}


def realized_yaw(result: RunResult, scenario: Scenario) -> np.ndarray:
    """Yaw of the task's yaw body from atan2(u_y, u_x), unwrapped (radians)."""
    offset = scenario.yaw_body_offset if scenario.yaw_body_offset is not None else scenario.tilt_body_offset
    u_axis = result.q[:, offset + 3 : offset + 6]
    return np.unwrap(np.arctan2(u_axis[:, 1], u_axis[:, 0]))


def tracked_position(result: RunResult, scenario: Scenario) -> np.ndarray:
    """The tracked point's position: σ_position + r_d."""
    return result.sigma[:, scenario.position_rows] + result.desired[:, :3]


def write_csv(path: Path, result: RunResult, scenario: Scenario) -> None:
    pos = tracked_position(result, scenario)
    yaw = np.degrees(realized_yaw(result, scenario))
    k, l = result.sigma.shape[1], result.u.shape[1]
    header = ["t", "x", "y", "z", "yaw_deg", "x_d", "y_d", "z_d", "yaw_d_deg"]
    header += [f"sigma_{i + 1}" for i in range(k)] + [f"u_{i + 1}" for i in range(l)]
    # Per cable: the tension at the start of the step after the instant, and 1 where it was slack.
    header += [f"tension_{name}_N" for name in result.cable_names] + [f"slack_{name}" for name in result.cable_names]
    columns = [result.t[:, None], pos, yaw[:, None], result.desired[:, :3], np.degrees(result.desired[:, 3:4]),
               result.sigma, result.u, result.cable_tension, (result.cable_active == 0).astype(float)]
    rows = np.hstack(columns).tolist()
    nc = len(result.cable_names)
    if nc:  # the slack flags as 0 / 1
        rows = [row[:-nc] + [int(v) for v in row[-nc:]] for row in rows]
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)


def write_summary(path: Path, spec_name: str, summaries: dict, duration: float, warnings: list[str],
                  extra: dict | None = None) -> None:
    doc = {"spec": spec_name, "duration_s": duration, "methods": summaries, "warnings": warnings, **(extra or {})}
    path.write_text(json.dumps(doc, indent=2) + "\n")


def format_table(summaries: dict) -> str:
    head = (f"{'method':<13} {'max pos':>8} {'rms pos':>8} {'max yaw':>8} {'max tilt':>8} {'max |phi|':>9} "
            f"{'tension range':>15} {'step median':>11} {'step mean':>9} {'p99':>7} {'MATLAB':>7}")
    units = (f"{'':<13} {'mm':>8} {'mm':>8} {'deg':>8} {'deg':>8} {'':>9} {'N':>15} "
             f"{'us':>11} {'us':>9} {'us':>7} {'us':>7}")
    lines = [head, units, "-" * len(head)]
    for method, s in summaries.items():
        if "error" in s:
            lines.append(f"{method:<13} cannot run: {s['error'][:90]}...")
            continue
        yaw = f"{s['max_yaw_error_deg']:8.4f}" if s["max_yaw_error_deg"] is not None else f"{'-':>8}"
        tension = (f"{s['min_winch_tension_N']:6.2f}..{s['max_winch_tension_N']:<6.2f}"
                   if s.get("min_winch_tension_N") is not None else "-")
        paper = PAPER_MATLAB_US.get(method)
        paper_s = f"{paper:7.1f}" if paper else f"{'-':>7}"
        step = s["control_step_us"]
        pos = (f"{s['max_position_error_mm']:8.4f} {s['rms_position_error_mm']:8.4f}"
               if s["max_position_error_mm"] is not None else f"{'unbounded':>17}")
        lines.append(
            f"{method:<13} {pos} {yaw} "
            f"{s['max_tilt_deg']:8.4f} {s['max_constraint_violation']:9.1e} {tension:>15} "
            f"{step['median']:11.1f} {step['mean']:9.1f} {step['p99']:7.1f} {paper_s}"
        )
    for method, s in summaries.items():
        if s.get("diverged_at_s") is not None:
            lines.append(f"{method}: diverged at t = {s['diverged_at_s']:.2f} s; the figures above stop there")
    lines.append("MATLAB: the paper's mean control-step time (R2019b, i7-8700). Paper bounds: 5.3 mm, 1.1 deg.")
    return "\n".join(lines)


def write_figures(out: Path, results: dict[str, RunResult], scenario: Scenario, summaries: dict,
                  input_names: list[str], servo_names: list[str], input_limits=None) -> list[Path]:
    """The run's figures; `input_limits` (min, max) per input are drawn on the inputs' panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    first = next(iter(results.values()))

    # Fig. 2 of the paper: desired and realized 3-D paths.
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    d = first.desired
    ax.plot(d[:, 0], d[:, 1], d[:, 2], "k--", lw=1.5, label="desired")
    for method, r in results.items():
        p = tracked_position(r, scenario)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], lw=1, label=method)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title("Desired and realized path of the tracked point")
    ax.legend(loc="upper left", fontsize=8)
    written.append(_save(fig, out / "path_3d.png"))

    # Fig. 3: servo-constraint errors over time (positions in mm).
    rows = range(scenario.position_rows.start, scenario.position_rows.stop)
    scales = [1e3 if i in rows else 1.0 for i in range(first.sigma.shape[1])]
    written.append(_stacked_time_series(
        {m: r.sigma * scales for m, r in results.items()}, results, servo_names,
        [f"σ{i + 1} [{'mm' if i in rows else '-'}]" for i in range(len(scales))],
        "Servo-constraint errors", out / "servo_errors.png", plt))
    # Inputs over time, held over each control period.
    written.append(_stacked_time_series(
        {m: r.u for m, r in results.items()}, results, input_names,
        [f"u{i + 1}" for i in range(first.u.shape[1])],
        "Inputs (held over each control period; dashed: limits)", out / "inputs.png", plt, held=True,
        limits=input_limits))

    # Control-step time per method beside the paper's MATLAB figures.
    methods = list(summaries)
    ours = [summaries[m]["control_step_us"]["mean"] for m in methods]
    medians = [summaries[m]["control_step_us"]["median"] for m in methods]
    paper = [PAPER_MATLAB_US.get(m, np.nan) for m in methods]
    x = np.arange(len(methods))
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar(x - 0.27, paper, 0.27, label="paper (MATLAB, i7-8700), mean")
    ax.bar(x, ours, 0.27, label="acroboter, mean")
    ax.bar(x + 0.27, medians, 0.27, label="acroboter, median")
    ax.set_xticks(x, methods)
    ax.set_yscale("log")
    ax.set_ylabel("control step [µs]")
    ax.set_title("Control-step compute time")
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3, which="both")
    written.append(_save(fig, out / "control_step_time.png"))
    return written


def _stacked_time_series(values: dict, results: dict, names: list[str], ylabels: list[str], title: str,
                         path: Path, plt, held: bool = False, limits=None) -> Path:
    """One panel per column of values[method] (samples x columns), every method in each panel.

    `limits`: (lower, upper) arrays, one entry per column; finite ones are drawn as dashed lines
    (a limit far from the data would squash the panel: the axis is kept on the data plus a margin)."""
    columns = len(names)
    fig, axes = plt.subplots(columns, 1, figsize=(9, 1.6 * columns + 1), sharex=True)
    axes = np.atleast_1d(axes)
    for method, data in values.items():
        t = results[method].t
        for i in range(columns):
            if held:
                axes[i].step(t, data[:, i], where="post", lw=0.8, label=method)
            else:
                axes[i].plot(t, data[:, i], lw=0.8, label=method)
    if limits is not None:
        for i, bounds in enumerate(zip(*limits, strict=True)):
            low = min(np.nanmin(d[:, i]) for d in values.values())
            high = max(np.nanmax(d[:, i]) for d in values.values())
            span = max(high - low, 1e-9)
            finite = [b for b in bounds if np.isfinite(b)]
            shown = [b for b in finite if low - 0.5 * span <= b <= high + 0.5 * span]
            for b in shown:
                axes[i].axhline(b, color="k", ls="--", lw=0.8)
            if shown:
                axes[i].set_ylim(min([low, *shown]) - 0.1 * span, max([high, *shown]) + 0.1 * span)
            off = [f"{'min' if b == bounds[0] else 'max'} {b:g}" for b in finite if b not in shown]
            if off:
                axes[i].text(0.99, 0.04, "limits off scale: " + ", ".join(off), transform=axes[i].transAxes,
                             fontsize=7, va="bottom", ha="right")
    for i in range(columns):
        axes[i].set_ylabel(ylabels[i], fontsize=8)
        axes[i].set_title(names[i], fontsize=8, loc="right")
        axes[i].grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=len(values))
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
