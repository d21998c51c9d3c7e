"""The run's figures and table (acroboter.report.figures, acroboter.report): the files, legends outside the
axes, labels with names and units, the tracking-error and magnified-path views, and paper=False."""

from __future__ import annotations

import dataclasses
import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import load_with_start
from matplotlib.image import imread

from acroboter.control.controllers import Gains, make_controller
from acroboter.report.figures import FIGURE_NAMES, build_figures, magnification, yaw_error_deg
from acroboter.report.report import format_table, write_figures
from acroboter.sim.records import Scenario, summarize
from acroboter.sim.simulation import setup_default, simulate

REPO = Path(__file__).resolve().parent.parent
METHODS = ("mlm", "penalty")


@pytest.fixture(scope="module")
def run():
    """1.5 s of the paper's crane under MLM and Penalty, with what run.py passes to write_figures."""
    spec, model, path, start = load_with_start(REPO / "model_spec" / "acroboter.toml")
    plant = setup_default(model, path)
    scenario = Scenario.from_model(model)
    results, summaries = {}, {}
    for method in METHODS:
        controller = make_controller(method, model, path, Gains.from_spec(spec))
        results[method] = simulate(model, path, controller, plant, start.q, 1.5, spec.controller.rate_hz,
                                   spec.simulation.step)
        summaries[method] = summarize(results[method], scenario, model.layout)
    lay = model.layout
    labels = [f"{name} [{unit}]" for name, unit in zip(lay.inputs, lay.input_units, strict=True)]
    return dict(results=results, scenario=scenario, summaries=summaries, input_names=labels,
                servo_names=lay.servo_constraints, input_limits=spec.input_limits()[:2])


def figures(run, **changes) -> dict:
    args = {**run, **changes}
    return build_figures(args["results"], args["scenario"], args["summaries"], args["input_names"],
                         args["servo_names"], input_limits=args["input_limits"], paper=args.get("paper", True))


@pytest.fixture(scope="module")
def built(run):
    figs = figures(run)
    for fig in figs.values():
        fig.canvas.draw()
    return figs


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR", path
    return struct.unpack(">II", data[16:24])


@pytest.mark.parametrize("paper", [True, False])
def test_write_figures_writes_every_png_and_returns_the_paths(run, tmp_path, paper):
    paths = write_figures(tmp_path, run["results"], run["scenario"], run["summaries"], run["input_names"],
                          run["servo_names"], input_limits=run["input_limits"], paper=paper)
    assert [p.name for p in paths] == list(FIGURE_NAMES)
    assert "tracking_errors.png" in FIGURE_NAMES
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(FIGURE_NAMES)  # nothing else
    for p in paths:
        width, height = png_size(p)
        assert 700 <= width <= 2000 and 400 <= height <= 2000, (p.name, width, height)
        pixels = imread(p)[..., :3]
        drawn = np.mean(pixels.min(axis=2) < 0.9)  # drawn, not blank (the file size varies with the timings)
        assert drawn > 0.02, (p.name, drawn)


def overlapping_legends(fig) -> list[str]:
    """Legends (figure's or axes') that overlap an axes' area or leave the figure."""
    renderer = fig.canvas.get_renderer()
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
    bad = []
    for legend in legends:
        box = legend.get_window_extent(renderer)
        bad += [f"legend over axes {i}" for i, ax in enumerate(fig.axes) if box.overlaps(ax.bbox)]
        if not (fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and fig.bbox.y0 <= box.y0 and box.y1 <= fig.bbox.y1):
            bad.append("legend outside the figure")
    return bad


def test_every_figure_has_a_legend_outside_the_axes(built):
    for name, fig in built.items():
        assert overlapping_legends(fig) == [], name
        assert fig.legends or any(ax.get_legend() for ax in fig.axes), f"{name}: no legend"


def test_the_legend_check_catches_a_legend_on_the_data(built):
    fig = built["servo_errors.png"]
    ax = fig.axes[0]
    ax.legend(loc="upper left")  # as the figures had it before
    fig.canvas.draw()
    try:
        assert overlapping_legends(fig) == ["legend over axes 0"]
    finally:
        ax.get_legend().remove()


def test_panel_notes_stay_out_of_the_axes(built):
    """The notes (σ1, 'limits off scale') are titles above the panel, not text on the data."""
    for name, fig in built.items():
        for ax in fig.axes:
            assert not ax.texts, (name, [t.get_text() for t in ax.texts])
    assert "limits off scale" in built["inputs.png"].axes[0].get_title(loc="right")


def ylabels(fig) -> list[str]:
    return [ax.get_ylabel().replace("\n", " ") for ax in fig.axes]


def test_inputs_are_labelled_with_names_and_units(run, built):
    assert ylabels(built["inputs.png"]) == run["input_names"]
    assert ylabels(built["inputs.png"])[:4] == ["tension_1 [N]", "tension_2 [N]", "tension_3 [N]",
                                                "yaw_torque [N·m]"]
    assert [ax.get_title(loc="right")[:2] for ax in built["inputs.png"].axes] == [f"u{i}" for i in range(1, 7)]


def test_limits_near_the_data_are_drawn_and_named_once_in_the_legend(run):
    u = np.vstack([r.u for r in run["results"].values()])
    lower, upper = np.full(u.shape[1], -np.inf), np.full(u.shape[1], np.inf)
    lower[0] = u[:, 0].min() - 0.2 * np.ptp(u[:, 0])  # tension_1 min, tension_2 max: near the data
    upper[1] = u[:, 1].max() + 0.2 * np.ptp(u[:, 1])
    lower[2] = u[:, 2].min() - 10 * np.ptp(u[:, 2])  # far from it: named in the title line, not drawn
    fig = figures(run, input_limits=(lower, upper))["inputs.png"]
    fig.canvas.draw()
    dashed = [[line.get_ydata()[0] for line in ax.get_lines() if line.get_label() == "input limit"]
              for ax in fig.axes]
    assert dashed == [[lower[0]], [upper[1]], [], [], [], []]
    assert legend_texts(fig) == [*METHODS, "input limit"]
    assert "dashed: input limits" in fig.get_suptitle()
    assert "limits off scale" not in fig.axes[0].get_title(loc="right")
    assert fig.axes[2].get_title(loc="right") == f"u3; limits off scale: min {lower[2]:g}"
    assert overlapping_legends(fig) == []


def test_servo_constraints_are_labelled_with_names_and_units(built):
    assert ylabels(built["servo_errors.png"]) == [
        "SU position x [mm]", "SU position y [mm]", "SU position z [mm]", "SU yaw via u [-]",
        "SU level w_x [-]", "SU level w_y [-]"]
    axes = built["servo_errors.png"].axes
    assert [ax.get_title(loc="right") for ax in axes] == [f"σ{i}" for i in range(1, 7)]


def test_servo_positions_are_drawn_in_mm(run, built):
    line = built["servo_errors.png"].axes[0].get_lines()[0]  # mlm, σ1
    np.testing.assert_allclose(line.get_ydata(), 1e3 * run["results"]["mlm"].sigma[:, 0])


def panel_max(ax) -> dict[str, float]:
    return {line.get_label(): float(np.abs(line.get_ydata()).max()) for line in ax.get_lines()}


def test_tracking_errors_are_the_summary_s(run, built):
    """Position-error norm, yaw error and tilt, every method in each panel; their maxima are the table's."""
    fig = built["tracking_errors.png"]
    assert ylabels(fig) == ["position error [mm]", "yaw error [deg]", "tilt [deg]"]
    keys = ("max_position_error_mm", "max_yaw_error_deg", "max_tilt_deg")
    for ax, key in zip(fig.axes, keys, strict=True):
        peaks = panel_max(ax)
        assert set(peaks) == set(METHODS)
        for method in METHODS:
            assert peaks[method] == pytest.approx(run["summaries"][method][key], rel=1e-9), (key, method)
            assert peaks[method] > 0


def test_yaw_error_is_wrapped(run):
    """A desired yaw a turn (2π) away is the same yaw: the error is the wrapped difference."""
    r = run["results"]["penalty"]
    turned = r.desired.copy()
    turned[:, 3] += 2 * np.pi * np.sign(np.arange(len(r.t)) % 2 - 0.5)  # ±2π alternately
    err = yaw_error_deg(r, run["scenario"])
    np.testing.assert_allclose(yaw_error_deg(dataclasses.replace(r, desired=turned), run["scenario"]), err,
                               atol=1e-9)
    assert np.abs(err).max() < 0.01


def test_a_crane_without_yaw_task_has_no_yaw_panel(run):
    scenario = dataclasses.replace(run["scenario"], yaw_body_offset=None)
    fig = figures(run, scenario=scenario)["tracking_errors.png"]
    assert ylabels(fig) == ["position error [mm]", "tilt [deg]"]


def test_path_figure_magnifies_the_error_and_says_by_how_much(run, built):
    factor = magnification(run["results"], run["scenario"])
    assert factor >= 100  # sub-millimetre errors on a path of centimetres
    fig = built["path_3d.png"]
    at_scale, magnified = fig.axes
    assert f"×{factor}" in magnified.get_title() and f"×{factor}" in fig.get_suptitle()
    r = run["results"]["mlm"]
    line = magnified.get_lines()[0]
    assert line.get_label() == "mlm, realized"
    x, y, z = line.get_data_3d()
    deviation = np.column_stack([x, y, z]) - r.desired[:, :3]
    np.testing.assert_allclose(deviation, factor * r.sigma[:, 0:3], atol=1e-12)
    # drawn at most a sixth of the path's extent, and at least a fifteenth (visible)
    extent = np.ptp(r.desired[:, :3], axis=0).max()
    worst = max(np.abs(res.sigma[:, 0:3]).max() for res in run["results"].values())
    assert extent / 15 <= factor * worst <= extent / 6
    x, y, z = at_scale.get_lines()[0].get_data_3d()
    np.testing.assert_allclose(np.column_stack([x, y, z]), r.desired[:, :3] + r.sigma[:, 0:3], atol=1e-15)


def test_magnification_is_one_for_an_error_visible_at_scale(run):
    big = {m: dataclasses.replace(r, sigma=r.sigma * 1e4) for m, r in run["results"].items()}
    assert magnification(big, run["scenario"]) == 1


def legend_texts(fig) -> list[str]:
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()]


def test_step_time_figure_shows_the_paper_s_times_only_for_the_paper_s_crane(run, built):
    paper = built["control_step_time.png"]
    assert any("MATLAB" in t for t in legend_texts(paper))
    assert len(paper.axes[0].containers) == 3
    # The scale follows the times shown, not the machine: log where they span a decade (the paper's
    # ~300 µs beside a quiet machine's ~15 µs), linear where they do not (a loaded machine's ~60 µs).
    for ours, scale in ((15.0, "log"), (60.0, "linear")):
        timed = {m: {**s, "control_step_us": {"median": ours, "mean": ours, "p99": 2 * ours}}
                 for m, s in run["summaries"].items()}
        assert figures(run, summaries=timed)["control_step_time.png"].axes[0].get_yscale() == scale, ours
    other = figures(run, paper=False)["control_step_time.png"]
    other.canvas.draw()
    texts = legend_texts(other)
    assert texts == ["acroboter, mean", "acroboter, median"]
    assert len(other.axes[0].containers) == 2
    assert "paper" not in other.axes[0].get_title()
    heights = [bar.get_height() for bar in other.axes[0].containers[0]]
    assert heights == pytest.approx([run["summaries"][m]["control_step_us"]["mean"] for m in METHODS])
    assert overlapping_legends(other) == []


def test_table_leaves_the_paper_s_numbers_out_for_other_cranes(run):
    paper = format_table(run["summaries"])
    assert "MATLAB" in paper and "Paper bounds" in paper and "309.1" in paper
    assert format_table(run["summaries"], paper=True) == paper
    other = format_table(run["summaries"], paper=False)
    assert "MATLAB" not in other and "Paper bounds" not in other and "paper" not in other.lower()
    assert "309.1" not in other
    lines = other.splitlines()
    assert lines[0].split()[0] == "method" and lines[0].rstrip().endswith("p99")
    assert len({len(line) for line in lines[:2]}) == 1  # the units line matches the header
    assert [line.split()[0] for line in lines[3:]] == list(METHODS)
    # the same rows, without the last column
    for with_paper, without in zip(paper.splitlines()[3:5], lines[3:5], strict=True):
        assert with_paper.startswith(without) and len(with_paper) == len(without) + 8
