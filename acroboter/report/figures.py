"""The run's figures (`python -m acroboter.run`): built as matplotlib Figures, then saved as PNGs.

`build_figures` returns the Figures by file name (the tests inspect them), `write_figures` saves them.
Every legend sits outside the axes (below them, `fig.legend(loc="outside lower center")` in a
constrained layout), so no legend covers data; notes on a panel go into its title line.
Matplotlib is driven through `matplotlib.figure.Figure` (no pyplot, no global backend switch).
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np

from ..sim.records import RunResult, Scenario, position_error_mm, tilt_deg, yaw_error_deg
from .paper import PAPER_MATLAB_US

# The files write_figures writes, in this order (run.py's FIGURES lists the same names).
FIGURE_NAMES = ("path_3d.png", "tracking_errors.png", "servo_errors.png", "inputs.png", "control_step_time.png")
DPI = 110


def magnification(results: dict[str, RunResult], scenario: Scenario, share: float = 0.15) -> int:
    """The largest 1-2-5 factor (1, 2, 5, 10, 20, ...) that draws the largest path error component
    as at most `share` of the path's extent (at least 1: an error visible at scale is not shrunk)."""
    first = next(iter(results.values()))
    extent = float(np.ptp(first.desired[:, :3], axis=0).max()) if len(first.t) else 0.0
    errors = [np.abs(r.sigma[:, scenario.position_rows]) for r in results.values() if len(r.t)]
    worst = max((float(np.nanmax(e)) for e in errors if np.isfinite(e).any()), default=0.0)
    if extent <= 0 or worst <= 0:
        return 1
    target = share * extent / worst
    if target < 2:
        return 1
    decade = 10 ** math.floor(math.log10(target))
    return int(max(m * decade for m in (1, 2, 5) if m * decade <= target))


def build_figures(results: dict[str, RunResult], scenario: Scenario, summaries: dict, input_names: list[str],
                  servo_names: list[str], input_limits=None, paper: bool = True) -> dict:
    """The run's figures by file name (FIGURE_NAMES, in that order), as matplotlib Figures.

    `input_names`: one y-label per input, with its unit ("tension_1 [N]"); `servo_names`: the
    layout's servo-constraint names (positions are drawn in mm, the other rows are dimensionless);
    `input_limits`: (lower, upper) arrays, one entry per input, drawn where finite; `paper`: the run
    is the paper's crane, so the control-step figure shows the paper's MATLAB times beside ours
    (False for any other crane: those times were measured on the paper's, and are left out)."""
    first = next(iter(results.values()))
    # One colour per method in every figure; each method drawn thinner than the one before, so that
    # methods whose lines coincide (penalty and iterative-N often do) all stay visible.
    styles = {m: dict(color=f"C{i % 10}", lw=max(0.6, 1.5 - 0.3 * i)) for i, m in enumerate(results)}
    figures = {"path_3d.png": _path_figure(results, scenario, styles)}
    figures["tracking_errors.png"] = _tracking_figure(results, scenario, styles)

    rows = range(scenario.position_rows.start, scenario.position_rows.stop)
    k = first.sigma.shape[1]
    scales = np.array([1e3 if i in rows else 1.0 for i in range(k)])
    figures["servo_errors.png"] = _stacked_time_series(
        {m: r.sigma * scales for m, r in results.items()}, results,
        [f"{servo_names[i]} [{'mm' if i in rows else '-'}]" for i in range(k)],
        [f"σ{i + 1}" for i in range(k)], "Servo-constraint errors σ (positions in mm, the other rows dimensionless)",
        styles)
    figures["inputs.png"] = _stacked_time_series(
        {m: r.u for m, r in results.items()}, results, list(input_names),
        [f"u{i + 1}" for i in range(first.u.shape[1])], "Inputs (held over each control period)", styles,
        held=True, limits=input_limits)
    figures["control_step_time.png"] = _step_time_figure(summaries, paper)
    return figures


def write_figures(out: Path, results: dict[str, RunResult], scenario: Scenario, summaries: dict,
                  input_names: list[str], servo_names: list[str], input_limits=None,
                  paper: bool = True) -> list[Path]:
    """Write the run's figures (FIGURE_NAMES) into `out` and return their paths.

    See build_figures for the arguments; `paper=False` (a crane that is not the paper's) leaves the
    paper's MATLAB times out of control_step_time.png."""
    figures = build_figures(results, scenario, summaries, input_names, servo_names, input_limits, paper)
    return [_save(fig, Path(out) / name) for name, fig in figures.items()]


def _figure(figsize):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)  # fig.canvas.draw() works (the tests measure the legends' places)
    return fig


def _legend_below(fig, handles=None, labels=None) -> None:
    """One legend for the whole figure, below the axes (outside them: it covers no data)."""
    if handles is None:
        handles, labels = [], []
        for ax in fig.axes:  # every entry once, in the order drawn
            for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
                if label not in labels:
                    handles.append(h)
                    labels.append(label)
    if not handles:
        return
    ncol = len(handles) if len(handles) <= 6 else math.ceil(len(handles) / 2)
    fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=8, frameon=False)


def _path_figure(results: dict[str, RunResult], scenario: Scenario, styles: dict):
    """Paper Fig. 2 at scale (left), and beside it the realized paths with their deviation from the
    desired path magnified (desired + factor · error), so that a sub-millimetre error shows."""
    first = next(iter(results.values()))
    d = first.desired[:, :3]
    factor = magnification(results, scenario)
    fig = _figure((13, 5.4))
    magnified = (f"error magnified ×{factor}: desired + {factor} · (realized − desired)" if factor > 1
                 else "error ×1: large enough to show at scale, not magnified")
    views = [("at scale", 1), (magnified, factor)]
    for col, (title, gain) in enumerate(views):
        ax = fig.add_subplot(1, 2, col + 1, projection="3d")
        drawn = [d]
        for method, r in results.items():
            p = r.desired[:, :3] + gain * r.sigma[:, scenario.position_rows]
            ax.plot(p[:, 0], p[:, 1], p[:, 2], **styles[method], label=f"{method}, realized")
            drawn.append(p)
        ax.plot(d[:, 0], d[:, 1], d[:, 2], "k--", lw=1.2, label="desired")  # on top: it shows at scale too
        _isotropic(ax, np.vstack(drawn))
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
        ax.set_title(title, fontsize=9)
    fig.suptitle("Desired and realized path of the tracked point" + (f" (right: error ×{factor})" if factor > 1
                                                                      else ""))
    handles, labels = fig.axes[0].get_legend_handles_labels()
    _legend_below(fig, handles[-1:] + handles[:-1], labels[-1:] + labels[:-1])  # desired first
    return fig


def _isotropic(ax, points: np.ndarray) -> None:
    """Same scale on x, y and z (a flat axis is widened to 0.4 of the widest), few ticks, no offset notation."""
    from matplotlib.ticker import MaxNLocator

    finite = points[np.isfinite(points).all(axis=1)]
    if not len(finite):
        return
    low, high = finite.min(axis=0), finite.max(axis=0)
    spans = np.maximum(high - low, max(0.4 * float((high - low).max()), 1e-3))
    centre = 0.5 * (low + high)
    for setter, c, s in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, spans, strict=True):
        setter(c - 0.55 * s, c + 0.55 * s)
    ax.set_box_aspect(tuple(spans / spans.max()), zoom=0.9)
    for axis, span in zip((ax.xaxis, ax.yaxis, ax.zaxis), spans, strict=True):
        axis.get_major_formatter().set_useOffset(False)
        axis.set_major_locator(MaxNLocator(max(2, round(6 * span / spans.max()))))


def _tracking_figure(results: dict[str, RunResult], scenario: Scenario, styles: dict):
    """Position-error norm, yaw error (with a yaw task) and tilt against time, every method in each."""
    panels = [("position error [mm]", "|tracked point − desired|", position_error_mm)]
    if scenario.yaw_body_offset is not None:
        panels.append(("yaw error [deg]", "realized − desired yaw, wrapped", yaw_error_deg))
    panels.append(("tilt [deg]", "tracked body's w axis from the vertical", tilt_deg))
    fig = _figure((9, 1.9 * len(panels) + 1.3))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (ylabel, note, values) in zip(axes, panels, strict=True):
        for method, r in results.items():
            ax.plot(r.t, values(r, scenario), **styles[method], label=method)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(note, fontsize=8, loc="right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("Tracking errors")
    _legend_below(fig)
    return fig


def _stacked_time_series(values: dict, results: dict, ylabels: list[str], tags: list[str], title: str,
                         styles: dict, held: bool = False, limits=None):
    """One panel per column of values[method] (samples x columns), every method in each panel.

    `ylabels`: each panel's name with its unit; `tags`: the column's short name (σ1, u1), in the
    panel's title line. `limits`: (lower, upper) arrays, one entry per column;
    finite ones are drawn as dashed lines (a limit far from the data would squash the panel: the
    axis is kept on the data plus a margin, and the title line names the limits off scale)."""
    columns = len(ylabels)
    fig = _figure((9, 1.6 * columns + 1.3))
    axes = fig.subplots(columns, 1, sharex=True, squeeze=False)[:, 0]
    for method, data in values.items():
        t = results[method].t
        for i in range(columns):
            if held:
                axes[i].step(t, data[:, i], where="post", **styles[method], label=method)
            else:
                axes[i].plot(t, data[:, i], **styles[method], label=method)
    notes = list(tags)
    limit_drawn = False
    if limits is not None:
        for i, bounds in enumerate(zip(*limits, strict=True)):
            data = [d[:, i][np.isfinite(d[:, i])] for d in values.values()]
            data = [d for d in data if d.size]
            if not data:
                continue
            low, high = min(d.min() for d in data), max(d.max() for d in data)
            span = max(high - low, 1e-9)
            finite = [b for b in bounds if np.isfinite(b)]
            shown = [b for b in finite if low - 0.5 * span <= b <= high + 0.5 * span]
            for b in shown:
                axes[i].axhline(b, color="k", ls="--", lw=0.8, label="input limit")
                limit_drawn = True
            if shown:
                axes[i].set_ylim(min([low, *shown]) - 0.1 * span, max([high, *shown]) + 0.1 * span)
            off = [f"{'min' if b == bounds[0] else 'max'} {b:g}" for b in finite if b not in shown]
            if off:
                notes[i] += "; limits off scale: " + ", ".join(off)
    for i in range(columns):
        axes[i].set_ylabel(_wrap(ylabels[i]), fontsize=8)
        axes[i].set_title(notes[i], fontsize=8, loc="right")
        axes[i].grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title + ("; dashed: input limits" if limit_drawn else ""))
    _legend_below(fig)
    return fig


def _wrap(label: str, width: int = 24) -> str:
    return label if len(label) <= width else textwrap.fill(label, width, break_on_hyphens=False)


def _step_time_figure(summaries: dict, paper: bool):
    """Mean and median control-step time per method; with paper=True beside the paper's MATLAB means."""
    methods = [m for m, s in summaries.items() if "control_step_us" in s]
    series = []
    if paper:
        series.append(("paper (MATLAB R2019b, i7-8700), mean", [PAPER_MATLAB_US.get(m, np.nan) for m in methods]))
    series.append(("acroboter, mean", [summaries[m]["control_step_us"]["mean"] for m in methods]))
    series.append(("acroboter, median", [summaries[m]["control_step_us"]["median"] for m in methods]))
    x = np.arange(len(methods))
    width = 0.8 / len(series)
    fig = _figure((8, 4.2))
    ax = fig.add_subplot()
    for j, (label, heights) in enumerate(series):
        ax.bar(x + (j - (len(series) - 1) / 2) * width, heights, width, label=label, color=f"C{j + (not paper)}")
    ax.set_xticks(x, methods)
    finite = [h for _, heights in series for h in heights if np.isfinite(h) and h > 0]
    if finite and max(finite) > 10 * min(finite):  # spans a decade (the paper's times beside ours): log
        ax.set_yscale("log")
    ax.set_ylabel("control step [µs]")
    ax.set_title("Control-step compute time" + (" beside the paper's" if paper else ""))
    ax.grid(axis="y", alpha=0.3, which="both")
    _legend_below(fig)
    return fig


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    return path
