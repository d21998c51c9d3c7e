"""`acroboter animate RESULTS_DIR`: a video of one method's run, drawn from its results folder alone.

    python -m acroboter.animate results                      # results/animation_<first method>.mp4
    acroboter animate results --method penalty --gif docs/run/acroboter.gif

Every frame: the ceiling at the height of the highest anchor, the anchors (a moving one where the
run recorded it), each cable from end to end coloured by its tension (one colour scale over the whole
run, dashed grey while slack), both bodies with their axes u, v, w (red, green, blue) and an outline
through their points, the desired path and the tracked point's trace so far, the time and the method.

The module has three parts: reading the folder (the CSV's pose columns q and the run's spec), the
geometry (every drawn point from q and the spec, pure numpy: `build_scene`), and the drawing and
encoding (matplotlib's Agg canvas, artists created once and updated per frame; imageio's ffmpeg for
MP4, Pillow for GIF). `--renderer auto` uses MuJoCo's offscreen renderer (the crane's MJCF model, MujocoFrames)
where it has an OpenGL context (EGL or OSMesa), else matplotlib, and says which and why (docs/animation.md).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import logging
import math
import os
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .entry import guarded, positive, progress_disabled, whole

log = logging.getLogger("acroboter")

AXES = ("u", "v", "w")
AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")  # u, v, w: red, green, blue
SLACK_COLOUR = "0.55"
TRACE_COLOUR = "#ff7f0e"
COLORMAP = "viridis"
BASE_WIDTH_IN = 6.4  # the figure's width in inches: --size sets the dpi, so the layout is the same at every size


class AnimationInputError(Exception):
    """The folder cannot be animated (bad input, exit 2): the message names the cause and the fix."""


class RendererUnavailable(Exception):
    """A renderer cannot run here (no OpenGL context, no model): `auto` falls back to matplotlib."""


# --- reading the folder ---------------------------------------------------------------------------


def read_summary(folder: Path) -> dict:
    if not folder.is_dir():
        what = "a file" if folder.exists() else "nothing"
        raise AnimationInputError(f"expected a results folder (as `acroboter run --out` writes), found {what} at "
                                  f"{folder}: give the folder that holds summary.json and the <method>.csv files")
    path = folder / "summary.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AnimationInputError(f"{folder} has no summary.json: give a folder written by `acroboter run`") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise AnimationInputError(f"{path} is not valid JSON ({err}): re-run `acroboter run` to write it") from None


def methods_that_ran(summary: dict, folder: Path) -> list[str]:
    """The methods of summary.json, in its order, that ran and left their CSV."""
    return [m for m, s in (summary.get("methods") or {}).items()
            if not (isinstance(s, dict) and "error" in s) and (folder / f"{m}.csv").is_file()]


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """A results CSV as {column: values}."""
    try:
        with path.open(newline="", encoding="utf-8") as f:
            header = next(csv.reader(f))
            values = np.loadtxt(f, delimiter=",", ndmin=2)
    except StopIteration:
        raise AnimationInputError(f"{path} is empty: re-run `acroboter run` to write it") from None
    except ValueError as err:
        raise AnimationInputError(f"{path} holds something other than numbers ({err}): "
                                  "re-run `acroboter run` to write it") from None
    if values.shape[0] == 0 or values.shape[1] != len(header):
        raise AnimationInputError(f"{path} has {values.shape[0]} rows of {values.shape[1]} numbers under a header of "
                                  f"{len(header)} columns: re-run `acroboter run` to write it")
    return {name: values[:, i] for i, name in enumerate(header)}


def spec_from_toml(text: str, source: str = "<spec>"):
    """A spec from its TOML text (what a results folder can carry, so that it never depends on a path)."""
    from .spec import SpecError, parse_spec

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SpecError(source, [("(syntax)", f"expected valid TOML, found a syntax error: {err}")]) from None
    return parse_spec(data, source)


def _spec_text_in(provenance: dict) -> str | None:
    """The spec's TOML text if the provenance carries it ('spec_toml', or 'spec': {'content'|'toml': ...})."""
    text = provenance.get("spec_toml")
    inner = provenance.get("spec")
    if text is None and isinstance(inner, dict):
        text = inner.get("content", inner.get("toml"))
    return text if isinstance(text, str) else None


def spec_of_run(summary: dict, folder: Path, override: Path | None = None):
    """The spec the run used: its TOML text in the provenance if there; else --spec; else the recorded path,
    else the example of that name, each only if its model (bodies, points, cables, anchors) is the run's."""
    from .locations import example_spec
    from .spec import load_spec

    provenance = summary.get("provenance") or {}
    wanted = provenance.get("spec_model_hash")
    text = _spec_text_in(provenance)
    if text is not None and override is None:
        return spec_from_toml(text, f"{folder / 'summary.json'} (provenance)")
    if override is not None:
        spec = load_spec(override)
        if wanted and spec.model_hash() != wanted:
            raise AnimationInputError(f"--spec {override} is not the crane of this run (its model hash differs from "
                                      f"the one in {folder / 'summary.json'}): give the spec the run used")
        return spec
    tried = []
    recorded = provenance.get("spec_file")
    candidates = [Path(recorded)] if recorded else []
    try:
        candidates.append(example_spec(str(summary.get("spec", ""))))
    except FileNotFoundError:
        pass
    for path in candidates:
        if not path.is_file():
            tried.append(f"{path} (not found)")
            continue
        if provenance.get("spec_sha256") == hashlib.sha256(path.read_bytes()).hexdigest():
            return load_spec(path)
        spec = load_spec(path)
        if wanted is None or spec.model_hash() == wanted:
            return spec
        tried.append(f"{path} (a different crane now)")
    raise AnimationInputError(f"cannot find the spec of the run in {folder}: tried {', '.join(tried) or 'nothing'}; "
                              "give it with --spec FILE")


# --- geometry: every drawn point from q and the spec (pure numpy) --------------------------------


@dataclass
class Scene:
    """What the frames show, per CSV row (N rows): positions in m, tensions in N."""

    t: np.ndarray  # (N,)
    tracked: np.ndarray  # (N, 3) the tracked point
    desired: np.ndarray  # (N, 3) its desired position
    centres: dict[str, np.ndarray]  # body -> (N, 3) r
    axes: dict[str, np.ndarray]  # body -> (N, 3, 3), rows u, v, w
    points: dict[str, np.ndarray]  # 'body.point' -> (N, 3)
    anchors: dict[str, np.ndarray]  # anchor -> (N, 3); a fixed one repeated
    moving: list[str]  # the anchors whose position the run recorded
    cables: list[str]
    ends: np.ndarray  # (N, C, 2, 3) each cable's two ends
    tension: np.ndarray  # (N, C)
    slack: np.ndarray  # (N, C) bool
    outlines: dict[str, list[str | None]]  # body -> its points in drawing order, None: lift the pen
    axis_length: dict[str, float]  # body -> length of its drawn axes
    ceiling_z: float
    limits: np.ndarray  # (3, 2) fixed axes limits: the whole run fits, same scale on every axis
    tension_range: tuple[float, float]  # of the taut cables over the whole run


def body_point(centre: np.ndarray, axes: np.ndarray, xi) -> np.ndarray:
    """p = r + ξ1 u + ξ2 v + ξ3 w for every row: centre (N, 3), axes (N, 3, 3) rows u, v, w."""
    return centre + np.einsum("k,nkj->nj", np.asarray(xi, dtype=float), axes)


def _column(columns: dict[str, np.ndarray], name: str, path: Path | None) -> np.ndarray:
    try:
        return columns[name]
    except KeyError:
        where = f"{path} has" if path is not None else "the columns have"
        raise AnimationInputError(
            f"{where} no column {name}: the pose (q_<body>.r_x_m, ..., q_<body>.w_z) and the moving anchors "
            "(anchor_<name>_x_m, ...) are needed to draw the crane; results written before acroboter recorded them "
            "lack them: re-run `acroboter run` to write them") from None


def outline_order(local: dict[str, np.ndarray]) -> list[str | None]:
    """A body's points in drawing order: the points off the body's w axis as a closed polygon (by their
    angle about w), then a spoke from each polygon corner to each point on the axis (a pyramid);
    with fewer than three points off the axis, a spoke from each point to the centre ('')."""
    off = [n for n, xi in local.items() if math.hypot(xi[0], xi[1]) > 1e-9]
    on = [n for n in local if n not in off]
    if len(off) < 3:
        order: list[str | None] = []
        for n in local:
            order += ["", n, None]
        return order
    off.sort(key=lambda n: math.atan2(local[n][1], local[n][0]))
    order = [*off, off[0]]
    for apex in on:
        for corner in off:
            order += [None, corner, apex]
    return order


def build_scene(spec, columns: dict[str, np.ndarray], path: Path | None = None) -> Scene:
    t = _column(columns, "t_s", path)
    n = len(t)
    stack = lambda names: np.column_stack([_column(columns, c, path) for c in names])  # noqa: E731
    centres, axes, points, local_points = {}, {}, {}, {}
    for body in spec.bodies:
        centres[body.name] = stack([f"q_{body.name}.r_{a}_m" for a in "xyz"])
        axes[body.name] = np.stack([stack([f"q_{body.name}.{e}_{a}" for a in "xyz"]) for e in AXES], axis=1)
        local_points[body.name] = {p: np.array(body.point(p), dtype=float) for p in body.points}
        for p, xi in local_points[body.name].items():
            points[f"{body.name}.{p}"] = body_point(centres[body.name], axes[body.name], xi)
    anchors, moving = {}, []
    for anchor in spec.anchors:
        names = [f"anchor_{anchor.name}_{a}_m" for a in "xyz"]
        if all(c in columns for c in names) or anchor.follows_path:
            anchors[anchor.name] = stack(names)
            moving.append(anchor.name)
        else:
            anchors[anchor.name] = np.tile(np.asarray(anchor.position, dtype=float), (n, 1))
    where = lambda end: anchors[end] if "." not in end else points[end]  # noqa: E731
    cables = [c.name for c in spec.cables]
    ends = np.stack([np.stack([where(c.ends[0]), where(c.ends[1])], axis=1) for c in spec.cables], axis=1) \
        if cables else np.zeros((n, 0, 2, 3))
    tension = np.column_stack([_column(columns, f"cable_{c}_tension_N", path) for c in cables]) if cables \
        else np.zeros((n, 0))
    slack = np.column_stack([_column(columns, f"cable_{c}_slack", path) for c in cables]).astype(bool) if cables \
        else np.zeros((n, 0), bool)
    tracked = stack(["x_m", "y_m", "z_m"])
    desired = stack(["x_d_m", "y_d_m", "z_d_m"])

    everything = np.concatenate([tracked, desired, *centres.values(), *points.values(), *anchors.values()])
    everything = everything[np.all(np.isfinite(everything), axis=1)]
    low, high = everything.min(axis=0), everything.max(axis=0)
    pad = 0.08 * float(np.max(high - low)) + 0.05
    limits = np.column_stack([low - pad, high + pad])
    ceiling_z = max((float(np.nanmax(a[:, 2])) for a in anchors.values()), default=float(high[2]))
    limits[2, 1] = max(limits[2, 1], ceiling_z + 1e-3)
    taut = tension[~slack & np.isfinite(tension)]
    lo, hi = (float(taut.min()), float(taut.max())) if taut.size else (0.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    arm = {b: 0.8 * max((float(np.linalg.norm(xi)) for xi in pts.values()), default=0.125)
           for b, pts in local_points.items()}
    return Scene(t=t, tracked=tracked, desired=desired, centres=centres, axes=axes, points=points, anchors=anchors,
                 moving=moving, cables=cables, ends=ends, tension=tension, slack=slack,
                 outlines={b: outline_order(pts) for b, pts in local_points.items()}, axis_length=arm,
                 ceiling_z=ceiling_z, limits=limits, tension_range=(lo, hi))


def outline_xyz(scene: Scene, body: str, row: int) -> np.ndarray:
    """The body's outline at one row as (K, 3), NaN rows where the pen lifts."""
    pts = []
    for name in scene.outlines[body]:
        if name is None:
            pts.append(np.full(3, np.nan))
        else:
            pts.append(scene.centres[body][row] if name == "" else scene.points[f"{body}.{name}"][row])
    return np.array(pts)


def frame_rows(t: np.ndarray, fps: float, speed: float) -> np.ndarray:
    """The CSV row each frame shows: frame k at run time t0 + k·speed/fps (the nearest row), the last frame at
    or before the end: floor(duration·fps/speed) + 1 frames (1376 for 55 s at 25 fps, real time)."""
    count = int(math.floor((t[-1] - t[0]) * fps / speed + 1e-9)) + 1
    wanted = t[0] + np.arange(count) * speed / fps
    right = np.clip(np.searchsorted(t, wanted), 1, len(t) - 1) if len(t) > 1 else np.zeros(count, int)
    if len(t) == 1:
        return right
    left = right - 1
    return np.where(np.abs(t[left] - wanted) <= np.abs(t[right] - wanted), left, right)


# --- drawing: matplotlib's Agg canvas, artists made once -----------------------------------------


class MatplotlibFrames:
    """Draws the scene at any row into an RGB array. The static part (axes, ceiling, fixed anchors, desired
    path, colorbar) is drawn once and kept as a bitmap; per frame only the moving artists are drawn on it."""

    def __init__(self, scene: Scene, method: str, size: tuple[int, int]):
        from matplotlib import colormaps
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize
        from matplotlib.figure import Figure
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        self.scene, self.size = scene, size
        width, height = size
        dpi = width / BASE_WIDTH_IN
        self.fig = fig = Figure(figsize=(BASE_WIDTH_IN, height / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(fig)
        ax = self.ax = fig.add_axes((-0.04, 0.03, 0.66, 0.93), projection="3d")
        lim = scene.limits
        ax.set_xlim(*lim[0])
        ax.set_ylim(*lim[1])
        ax.set_zlim(*lim[2])
        ax.set_box_aspect(tuple(lim[:, 1] - lim[:, 0]), zoom=1.0)  # equal scale on x, y, z
        ax.view_init(elev=18, azim=-55)
        ax.set_xlabel("x [m]", fontsize=7, labelpad=-4)
        ax.set_ylabel("y [m]", fontsize=7, labelpad=-4)
        ax.set_zlabel("z [m]", fontsize=7, labelpad=-4)
        ax.tick_params(labelsize=6, pad=-2)
        ax.computed_zorder = False

        (x0, x1), (y0, y1), z = lim[0], lim[1], scene.ceiling_z
        ax.add_collection3d(Poly3DCollection([[(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]],
                                             facecolor="0.6", edgecolor="0.4", alpha=0.18, linewidths=0.5))
        fixed = [a for a in scene.anchors if a not in scene.moving]
        if fixed:
            xyz = np.array([scene.anchors[a][0] for a in fixed])
            ax.plot(xyz[:, 0], xyz[:, 1], xyz[:, 2], "ks", ms=4, ls="none")
        d = scene.desired
        ax.plot(d[:, 0], d[:, 1], d[:, 2], color="0.35", lw=0.6, ls=":", label="desired path")

        self.norm = Normalize(*scene.tension_range)
        self.cmap = colormaps[COLORMAP]
        bar = fig.colorbar(ScalarMappable(norm=self.norm, cmap=self.cmap), cax=fig.add_axes((0.64, 0.16, 0.32, 0.025)),
                           orientation="horizontal")
        bar.set_label("cable tension [N] (dashed grey: slack)", fontsize=7)
        bar.ax.tick_params(labelsize=6)

        # The tracked point from above, zoomed on its path (the 3-D view shows the whole crane).
        top = self.top = fig.add_axes((0.66, 0.36, 0.30, 0.50))
        span = np.concatenate([scene.desired, scene.tracked])[:, :2]
        span = span[np.all(np.isfinite(span), axis=1)]
        centre, half = (span.min(0) + span.max(0)) / 2, max(float(np.ptp(span, axis=0).max()) * 0.6, 0.01)
        top.set_xlim(centre[0] - half, centre[0] + half)
        top.set_ylim(centre[1] - half, centre[1] + half)
        top.set_aspect("equal")
        top.plot(d[:, 0], d[:, 1], color="0.35", lw=0.6, ls=":")
        top.set_title("tracked point, from above", fontsize=7)
        top.set_xlabel("x [m]", fontsize=6, labelpad=1)
        top.set_ylabel("y [m]", fontsize=6, labelpad=1)
        top.tick_params(labelsize=5)
        top.grid(alpha=0.3)

        line = lambda **kw: ax.plot([], [], [], animated=True, **kw)[0]  # noqa: E731
        self.trace = line(color=TRACE_COLOUR, lw=1.0)
        self.tracked = line(marker="o", ms=3, color=TRACE_COLOUR, ls="none")
        self.moving = line(marker="s", ms=4, color="k", ls="none")
        self.cable_lines = [line(lw=1.6, solid_capstyle="round") for _ in scene.cables]
        self.outlines = {b: line(color="0.15", lw=1.0) for b in scene.centres}
        self.axis_lines = {b: [line(color=c, lw=1.4) for c in AXIS_COLOURS] for b in scene.centres}
        self.top_trace = top.plot([], [], color=TRACE_COLOUR, lw=1.0, animated=True)[0]
        self.top_point = top.plot([], [], "o", color=TRACE_COLOUR, ms=3, animated=True)[0]
        self.clock = fig.text(0.02, 0.95, "", fontsize=9, family="monospace", animated=True)
        fig.text(0.98, 0.95, method, fontsize=9, ha="right", weight="bold")
        self.moving_artists = [self.trace, self.tracked, self.moving, *self.cable_lines, *self.outlines.values(),
                               *(a for lines in self.axis_lines.values() for a in lines)]
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)

    def update(self, row: int) -> None:
        """Set every moving artist's data to the scene at `row` (no drawing)."""
        s = self.scene
        tr = s.tracked[: row + 1]
        self.trace.set_data_3d(tr[:, 0], tr[:, 1], tr[:, 2])
        self.tracked.set_data_3d(tr[-1:, 0], tr[-1:, 1], tr[-1:, 2])
        if s.moving:
            m = np.array([s.anchors[a][row] for a in s.moving])
            self.moving.set_data_3d(m[:, 0], m[:, 1], m[:, 2])
        for c, artist in enumerate(self.cable_lines):
            a, b = s.ends[row, c]
            artist.set_data_3d([a[0], b[0]], [a[1], b[1]], [a[2], b[2]])
            if s.slack[row, c]:
                artist.set_color(SLACK_COLOUR)
                artist.set_linestyle("--")
                artist.set_linewidth(1.0)
            else:
                artist.set_color(self.cmap(self.norm(s.tension[row, c])))
                artist.set_linestyle("-")
                artist.set_linewidth(1.6)
        for body, artist in self.outlines.items():
            o = outline_xyz(s, body, row)
            artist.set_data_3d(o[:, 0], o[:, 1], o[:, 2])
            r = s.centres[body][row]
            for k, axis_line in enumerate(self.axis_lines[body]):
                tip = r + s.axis_length[body] * s.axes[body][row, k]
                axis_line.set_data_3d([r[0], tip[0]], [r[1], tip[1]], [r[2], tip[2]])
        self.top_trace.set_data(tr[:, 0], tr[:, 1])
        self.top_point.set_data(tr[-1:, 0], tr[-1:, 1])
        self.clock.set_text(f"t = {s.t[row]:6.2f} s")

    def render(self, row: int) -> np.ndarray:
        """The frame at `row` as an (H, W, 3) uint8 array."""
        self.update(row)
        self.canvas.restore_region(self.background)
        for artist in self.moving_artists:
            self.ax.draw_artist(artist)
        self.top.draw_artist(self.top_trace)
        self.top.draw_artist(self.top_point)
        self.fig.draw_artist(self.clock)
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()


# --- MuJoCo's offscreen renderer -------------------------------------------------------------------

_GL_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom type="sphere" size=".1"/></worldbody></mujoco>')
r = mujoco.Renderer(m, 8, 8)
r.update_scene(mujoco.MjData(m))
r.render()
r.close()
print("ok")
"""

GL_FIX = ("MuJoCo's offscreen renderer needs an OpenGL context, and without a display that is MUJOCO_GL=egl "
          "(libEGL; Mesa's software renderer works without a GPU: apt-get install libegl1 libgl1-mesa-dri) or "
          "MUJOCO_GL=osmesa (apt-get install libosmesa6)")
SLACK_RGBA = (0.55, 0.55, 0.55, 0.45)  # a slack cable: grey, translucent and thinner
TRACE_RGBA = (1.0, 0.498, 0.055, 1.0)  # TRACE_COLOUR
PANEL_RGB = (38, 38, 42)  # the colour bar's and the top view's background (MuJoCo's is black)
BODY_ALPHA = 0.3  # the bodies' discs, see-through: the axes inside them show
PATH_POINTS = 400  # the desired path and the trace are drawn through at most this many rows each
VIEW_SHARE = 0.6  # of the image's width that holds the crane
AZIMUTH, ELEVATION = 125.0, -18.0  # the camera: the matplotlib view (azim -55, elev 18) in MuJoCo's convention


def probe_gl(timeout: float = 60.0) -> tuple[str | None, str]:
    """(MUJOCO_GL value that works, why) by creating a tiny mujoco.Renderer in a subprocess (a failing GL
    library can abort the process; this one stays clean). MUJOCO_GL from the environment is tried alone.
    mujoco is not imported here: it picks its GL backend from MUJOCO_GL once, when first imported."""
    import importlib.util

    if importlib.util.find_spec("mujoco") is None:
        return None, "mujoco is not installed"
    given = os.environ.get("MUJOCO_GL")
    reasons = []
    for backend in [given] if given else ["egl", "osmesa"]:
        env = {**os.environ, "MUJOCO_GL": backend}
        if backend != "egl":
            env.setdefault("PYOPENGL_PLATFORM", backend)
        try:
            proc = subprocess.run([sys.executable, "-c", _GL_PROBE], env=env, capture_output=True, text=True,
                                  timeout=timeout)
        except subprocess.TimeoutExpired:
            reasons.append(f"MUJOCO_GL={backend}: no answer in {timeout:g} s")
            continue
        if proc.returncode == 0 and proc.stdout.strip().endswith("ok"):
            return backend, f"MUJOCO_GL={backend} gives an OpenGL context"
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        reasons.append(f"MUJOCO_GL={backend}: {last[:160]}")
    return None, "; ".join(reasons)


def _mujoco_module():
    """mujoco with the GL backend of MUJOCO_GL (set by choose_renderer). mujoco reads MUJOCO_GL when first
    imported: where it was imported before (by another part of the program), its context class is replaced."""
    backend = os.environ.setdefault("MUJOCO_GL", "egl")
    if backend == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    import importlib

    import mujoco
    from mujoco import gl_context

    if backend in ("egl", "osmesa") and getattr(gl_context, "_MUJOCO_GL", backend) != backend:
        gl_context.GLContext = importlib.import_module(f"mujoco.{backend}").GLContext
    return mujoco


def _mujoco_ready(spec) -> None:
    """Raise RendererUnavailable unless the MuJoCo backend can draw this spec: its MJCF model must build."""
    from .mjcf_model import mjcf_xml
    from .spec import SpecError

    try:
        mjcf_xml(spec)
    except SpecError as err:
        raise RendererUnavailable(f"MuJoCo cannot represent this crane ({err})") from None


class _RecordedAnchors:
    """What MujocoPlant.set_state reads from the desired path, [s, ṡ, s̈] at t: here the moving anchors where
    the run recorded them (`row` is filled before each set_state; rates zero, only positions are drawn)."""

    def __init__(self, n_signals: int):
        self.row = np.zeros((1, 3 * n_signals))

    def table(self, times) -> np.ndarray:
        return self.row


def camera_pose(limits: np.ndarray, fovy_deg: float, aspect: float, azimuth: float = AZIMUTH,
                elevation: float = ELEVATION, margin: float = 1.04) -> tuple[np.ndarray, float]:
    """(lookat, distance) of a free camera at (azimuth, elevation) that holds the whole box `limits` (3, 2):
    the nearest distance at which every corner is inside the vertical and the horizontal field of view."""
    lookat = limits.mean(axis=1)
    forward, right, up = camera_axes(azimuth, elevation)
    ty = math.tan(math.radians(fovy_deg) / 2)
    tx = ty * aspect
    distance = 0.0
    for corner in np.array(np.meshgrid(*limits, indexing="ij")).reshape(3, -1).T:
        p = corner - lookat
        depth = float(p @ forward)
        distance = max(distance, abs(p @ up) / ty - depth, abs(p @ right) / tx - depth)
    return lookat, margin * distance


def camera_axes(azimuth: float, elevation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MuJoCo's free camera: it looks along (cos a cos e, sin a cos e, sin e), with z up on the image."""
    a, e = math.radians(azimuth), math.radians(elevation)
    forward = np.array([math.cos(a) * math.cos(e), math.sin(a) * math.cos(e), math.sin(e)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return forward, right, np.cross(right, forward)


class MujocoFrames:
    """Draws the scene at any row with MuJoCo's offscreen renderer. The crane is its MJCF model
    (acroboter.mjcf_model) posed from the row's q by MujocoPlant.set_state, the moving anchors where the run
    recorded them; the cables are its visible tendons, coloured per frame by tension (the matplotlib renderer's
    colormap and range) or grey, translucent and thin while slack. Added to MuJoCo's scene per frame: the bodies'
    axes u, v, w (arrows), their outlines, the desired path and the trace so far (lines through at most
    PATH_POINTS rows). The clock, the method and a colour bar are drawn onto the image (Pillow). The ceiling
    plane becomes a box over the run's extent (MuJoCo draws a plane as a grid of its 1 cm spacing: 40 ms a frame
    in software). close() releases the GL context (EGL fails at interpreter exit otherwise)."""

    def __init__(self, scene: Scene, spec, method: str, size: tuple[int, int]):
        mujoco = self.mj = _mujoco_module()
        from types import SimpleNamespace

        from matplotlib import colormaps
        from matplotlib.colors import Normalize

        from .layout import build_layout
        from .mujoco_plant import MujocoPlant

        self.scene, self.size, self.method = scene, size, method
        layout = build_layout(spec)
        # MujocoPlant reads only the spec and its layout from the model: no compiled library is needed.
        self.signals = _RecordedAnchors(layout.n_signals)
        self.plant = MujocoPlant(SimpleNamespace(spec=spec, layout=layout), self.signals)
        m, self.data = self.plant.mj_model, self.plant.mj_data
        self.model = m
        self.anchor_signals = [(a, layout.anchor_signal[a]) for a in scene.moving if a in layout.anchor_signal]
        self.q = np.zeros((len(scene.t), layout.n))
        for body, i in layout.body_offset.items():
            self.q[:, i : i + 3] = scene.centres[body]
            self.q[:, i + 3 : i + 12] = scene.axes[body].reshape(-1, 9)  # rows u, v, w
        for c, cable in enumerate(scene.cables):
            if cable in layout.winch_index:  # the drum's length only routes the invisible tendon: the free span
                self.q[:, layout.winch_index[cable]] = np.linalg.norm(scene.ends[:, c, 1] - scene.ends[:, c, 0], axis=1)
        self.qd = np.zeros(layout.n)

        lim = scene.limits
        extent = float(np.max(lim[:, 1] - lim[:, 0]))
        ceiling = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ceiling")
        if ceiling >= 0:
            m.geom_type[ceiling] = mujoco.mjtGeom.mjGEOM_BOX
            m.geom_size[ceiling] = [(lim[0, 1] - lim[0, 0]) / 2, (lim[1, 1] - lim[1, 0]) / 2, 0.002 * extent]
            m.geom_pos[ceiling] = [lim[0].mean(), lim[1].mean(), scene.ceiling_z]
        for body in scene.centres:
            shape = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{body}.shape")
            if shape >= 0:
                m.geom_rgba[shape, 3] = BODY_ALPHA
        self.tendons = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, c) for c in scene.cables], int)
        self.cable_width = max(float(m.tendon_width[self.tendons].max(initial=0.0)), 0.003 * extent)
        self.cmap, self.norm = colormaps[COLORMAP], Normalize(*scene.tension_range)
        self.arrow_width, self.marker = 0.006 * extent, 0.008 * extent

        width, height = size
        m.vis.global_.offwidth = max(width, m.vis.global_.offwidth)
        m.vis.global_.offheight = max(height, m.vis.global_.offheight)
        m.vis.quality.shadowsize = 0  # no shadows: no 4096² shadow map to draw in software
        m.vis.map.zfar = 50.0
        self.path_rows = np.unique(np.linspace(0, len(scene.t) - 1, min(len(scene.t), PATH_POINTS)).round().astype(int))
        added = 2 * len(self.path_rows) + sum(3 + len(o) for o in scene.outlines.values()) + 16
        self.renderer = mujoco.Renderer(m, height, width, max_geom=m.ngeom + m.nsite + 4 * m.ntendon + 64 + added)
        self.option = mujoco.MjvOption()
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        # The crane in the left VIEW_SHARE of the image (the top view is on the right): fitted to that share's
        # aspect, then moved left by turning the look-at point to the right.
        fovy = float(m.vis.global_.fovy)
        lookat, distance = camera_pose(lim, fovy, VIEW_SHARE * width / height)
        right = camera_axes(AZIMUTH, ELEVATION)[1]
        shift = (1 - VIEW_SHARE) * distance * math.tan(math.radians(fovy) / 2) * width / height
        self.camera.lookat[:] = lookat + shift * right
        self.camera.distance, self.camera.azimuth, self.camera.elevation = distance, AZIMUTH, ELEVATION
        self.eye = np.eye(3).reshape(-1)
        self._overlay_init()

    # --- per frame -------------------------------------------------------------------------------------------
    def update(self, row: int) -> None:
        """Pose the model at `row` and colour its tendons (no drawing)."""
        s, m = self.scene, self.model
        for anchor, j in self.anchor_signals:
            self.signals.row[0, j : j + 3] = s.anchors[anchor][row]
        self.plant.set_state(self.q[row], self.qd, float(s.t[row]))
        for c, tendon in enumerate(self.tendons):
            if tendon < 0:
                continue
            if s.slack[row, c]:
                m.tendon_rgba[tendon] = SLACK_RGBA
                m.tendon_width[tendon] = 0.4 * self.cable_width
            else:
                m.tendon_rgba[tendon] = self.cmap(self.norm(s.tension[row, c]))
                m.tendon_width[tendon] = self.cable_width

    def render(self, row: int) -> np.ndarray:
        """The frame at `row` as an (H, W, 3) uint8 array."""
        mj, s = self.mj, self.scene
        self.update(row)
        r = self.renderer
        r.update_scene(self.data, camera=self.camera, scene_option=self.option)
        r.scene.flags[mj.mjtRndFlag.mjRND_SHADOW] = 0
        r.scene.flags[mj.mjtRndFlag.mjRND_REFLECTION] = 0
        line, arrow = mj.mjtGeom.mjGEOM_LINE, mj.mjtGeom.mjGEOM_ARROW
        d = s.desired[self.path_rows]
        for a, b in zip(d[:-1], d[1:], strict=True):
            self._connect(line, 1.0, a, b, (0.35, 0.35, 0.35, 1.0))
        trace = s.tracked[[*self.path_rows[self.path_rows < row], row]]
        for a, b in zip(trace[:-1], trace[1:], strict=True):
            self._connect(line, 2.0, a, b, TRACE_RGBA)
        self._geom(mj.mjtGeom.mjGEOM_SPHERE, [self.marker] * 3, s.tracked[row], TRACE_RGBA)
        for body in s.outlines:
            o = outline_xyz(s, body, row)
            for a, b in zip(o[:-1], o[1:], strict=True):
                if np.isfinite(a).all() and np.isfinite(b).all():
                    self._connect(line, 1.5, a, b, (0.15, 0.15, 0.15, 1.0))
            centre = s.centres[body][row]
            for k, colour in enumerate(AXIS_RGBA):
                tip = centre + s.axis_length[body] * s.axes[body][row, k]
                self._connect(arrow, self.arrow_width, centre, tip, colour)
        frame = r.render()
        self._overlay(frame, row)
        return frame

    def _geom(self, kind, size, pos, rgba):
        scn = self.renderer.scene
        if scn.ngeom >= scn.maxgeom:
            return None
        g = scn.geoms[scn.ngeom]
        self.mj.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float), self.eye,
                             np.asarray(rgba, np.float32))
        scn.ngeom += 1
        return g

    def _connect(self, kind, width, a, b, rgba):
        g = self._geom(kind, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], rgba)
        if g is not None:
            self.mj.mjv_connector(g, kind, width, np.asarray(a, float), np.asarray(b, float))

    # --- text and colour bar on the image (Pillow) ------------------------------------------------------------
    def _overlay_init(self) -> None:
        """The static parts drawn once: the colour bar (bottom right) and the top view's box with the desired path
        (top right, the tracked point from above, zoomed on its path as the matplotlib renderer's)."""
        from PIL import Image, ImageDraw, ImageFont

        width, height = self.size
        self.font = ImageFont.load_default(size=max(9, round(height * 0.028)))
        small = ImageFont.load_default(size=max(8, round(height * 0.02)))
        self.band = max(12, round(height * 0.05))  # the strip at the top that holds the clock and the method
        pad = max(2, round(height * 0.008))
        bar_w, bar_h = max(60, round(width * 0.3)), max(4, round(height * 0.018))
        text_h = small.size + pad
        legend = Image.new("RGB", (bar_w + 2 * pad + 2 * small.size, bar_h + 2 * text_h + 2 * pad), PANEL_RGB)
        draw = ImageDraw.Draw(legend)
        colours = (255 * self.cmap(np.linspace(0, 1, bar_w))[:, :3]).round().astype(np.uint8)
        x0 = pad + small.size
        legend.paste(Image.fromarray(np.repeat(colours[None], bar_h, axis=0)), (x0, pad + text_h))
        lo, hi = self.scene.tension_range
        draw.text((x0, pad), "cable tension [N] (grey: slack)", fill="white", font=small)
        draw.text((x0, pad + text_h + bar_h + 1), f"{lo:.3g}", fill="white", font=small)
        draw.text((x0 + bar_w, pad + text_h + bar_h + 1), f"{hi:.3g}", fill="white", font=small, anchor="ra")
        self.legend = np.asarray(legend)
        self.legend_at = (max(0, height - self.legend.shape[0] - pad), max(0, width - self.legend.shape[1] - pad))

        s = self.scene
        side = max(32, round(0.36 * min(width, 1.4 * height)))
        span = np.concatenate([s.desired, s.tracked])[:, :2]
        span = span[np.all(np.isfinite(span), axis=1)]
        centre, half = (span.min(0) + span.max(0)) / 2, max(float(np.ptp(span, axis=0).max()) * 0.6, 0.01)
        inner = side - 2 * pad
        to_px = lambda xy: np.column_stack([pad + (xy[:, 0] - centre[0] + half) / (2 * half) * inner,  # noqa: E731
                                            pad + text_h + (centre[1] + half - xy[:, 1]) / (2 * half) * inner])
        self.top_px = to_px(s.tracked[:, :2])
        top = Image.new("RGB", (side, side + text_h), PANEL_RGB)
        draw = ImageDraw.Draw(top)
        draw.text((pad, pad // 2), f"tracked point from above, {200 * half:.3g} cm across", fill="white", font=small)
        draw.rectangle((pad, pad + text_h, pad + inner, pad + text_h + inner), outline=(110, 110, 110))
        desired = to_px(s.desired[self.path_rows, :2])
        draw.line([tuple(p) for p in desired[np.all(np.isfinite(desired), axis=1)]], fill=(150, 150, 150), width=1)
        self.top = np.asarray(top)
        self.top_at = (self.band, max(0, width - side - pad))
        self.trace_rgb = tuple(round(255 * c) for c in TRACE_RGBA[:3])
        self.trace_width = max(1, round(height / 360))

    def _overlay(self, frame: np.ndarray, row: int) -> None:
        from PIL import Image, ImageDraw

        h, w = frame.shape[:2]
        y, x = self.legend_at
        patch = self.legend[: h - y, : w - x]
        frame[y : y + patch.shape[0], x : x + patch.shape[1]] = patch
        y, x = self.top_at
        top = Image.fromarray(self.top[: h - y, : w - x].copy())
        trace = self.top_px[[*self.path_rows[self.path_rows < row], row]]
        trace = [tuple(p) for p in trace[np.all(np.isfinite(trace), axis=1)]]
        draw = ImageDraw.Draw(top)
        if len(trace) > 1:
            draw.line(trace, fill=self.trace_rgb, width=self.trace_width)
        if trace:
            (px, py), r = trace[-1], self.trace_width + 1
            draw.ellipse((px - r, py - r, px + r, py + r), fill=self.trace_rgb)
        frame[y : y + top.height, x : x + top.width] = np.asarray(top)
        band = Image.fromarray(frame[: self.band])
        draw = ImageDraw.Draw(band)
        pad = round(self.band * 0.2)
        draw.text((pad, pad), f"t = {self.scene.t[row]:6.2f} s", fill="white", font=self.font)
        draw.text((self.size[0] - pad, pad), self.method, fill="white", font=self.font, anchor="ra")
        frame[: self.band] = np.asarray(band)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None


AXIS_RGBA = tuple((*(int(c[i : i + 2], 16) / 255 for i in (1, 3, 5)), 1.0) for c in AXIS_COLOURS)


def _mujoco_frames(scene: Scene, spec, rows: np.ndarray, size: tuple[int, int], method: str) -> Iterator[np.ndarray]:
    frames = MujocoFrames(scene, spec, method, size)
    try:
        for row in rows:
            yield frames.render(int(row))
    finally:
        frames.close()


def _matplotlib_frames(scene: Scene, spec, rows: np.ndarray, size: tuple[int, int], method: str):
    frames = MatplotlibFrames(scene, method, size)
    for row in rows:
        yield frames.render(int(row))


def choose_renderer(requested: str, spec):
    """(name, frame generator) for --renderer; `auto`: MuJoCo where it has a GL context and can draw the spec,
    else matplotlib, with one log line saying which and why."""
    if requested == "matplotlib":
        return "matplotlib", _matplotlib_frames
    backend, why = probe_gl()
    if backend is not None:
        try:
            _mujoco_ready(spec)
        except RendererUnavailable as err:
            why = f"{why}, but {err}"
        else:
            os.environ["MUJOCO_GL"] = backend
            log.info(f"renderer: mujoco ({why})")
            return "mujoco", _mujoco_frames
        if requested == "mujoco":
            raise RendererUnavailable(f"--renderer mujoco cannot run here: {why}")
    elif requested == "mujoco":
        raise RendererUnavailable(f"--renderer mujoco cannot run here ({why}): {GL_FIX}")
    log.info(f"renderer: matplotlib (MuJoCo's is not usable here: {why})")
    return "matplotlib", _matplotlib_frames


# --- encoding -------------------------------------------------------------------------------------


def write_mp4(frames: Iterator[np.ndarray], path: Path, fps: float, total: int, quiet: bool) -> int:
    """H.264 in yuv420p (plays everywhere); even frame sizes, so no resizing. Returns the frame count."""
    import imageio.v2 as imageio
    from tqdm import tqdm

    count = 0
    writer = imageio.get_writer(path, fps=fps, codec="libx264", quality=7, pixelformat="yuv420p",
                                macro_block_size=2, ffmpeg_log_level="error")
    try:
        for frame in tqdm(frames, total=total, unit="frame", desc=f"rendering {path.name}",
                          disable=progress_disabled(quiet), file=sys.stderr):
            writer.append_data(frame)
            count += 1
    finally:
        writer.close()
    return count


def drawing_colours(samples: int = 48) -> list[tuple[int, int, int]]:
    """The colours the moving artists use (axes, trace, slack, outline, the tension colormap): kept exact in a
    GIF's palette even when the first frame does not show them yet."""
    from matplotlib import colormaps
    from matplotlib.colors import to_rgb

    rgb = [to_rgb(c) for c in (*AXIS_COLOURS, TRACE_COLOUR, SLACK_COLOUR, "0.15", "k", "w")]
    rgb += [colormaps[COLORMAP](x)[:3] for x in np.linspace(0, 1, samples)]
    return [tuple(round(255 * v) for v in c) for c in rgb]


def write_gif(frames: Iterator[np.ndarray], path: Path, fps: float, total: int, quiet: bool) -> int:
    """A looping GIF with one palette (the first frame's colours and the drawing's own) and no dithering: the
    static background stays identical between frames, and Pillow stores only each frame's changed rectangle."""
    from PIL import Image
    from tqdm import tqdm

    images, palette = [], None
    for frame in tqdm(frames, total=total, unit="frame", desc=f"rendering {path.name}",
                      disable=progress_disabled(quiet), file=sys.stderr):
        image = Image.fromarray(frame)
        if palette is None:
            own = drawing_colours()
            first = image.quantize(colors=256 - len(own), method=Image.Quantize.MEDIANCUT).getpalette()
            palette = Image.new("P", (1, 1))
            palette.putpalette([*first[: 3 * (256 - len(own))], *(v for c in own for v in c)])
        images.append(image.quantize(palette=palette, dither=Image.Dither.NONE))
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0,
                   optimize=False, disposal=1)
    return len(images)


# --- the command line -----------------------------------------------------------------------------


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels such as 960x720, found '{text}'") from None
    if not (64 <= w <= 7680 and 64 <= h <= 4320):
        raise argparse.ArgumentTypeError(f"expected a size between 64x64 and 7680x4320, found {w}x{h}")
    return w + w % 2, h + h % 2  # H.264 in yuv420p needs even sizes: an odd one grows by a pixel


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="acroboter animate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", type=Path, metavar="RESULTS_DIR", help="a folder written by `acroboter run --out`")
    p.add_argument("--method", default=None, help="the method to show (default: the first in summary.json that ran)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.mp4",
                   help="the MP4 to write (default: RESULTS_DIR/animation_<method>.mp4)")
    p.add_argument("--gif", type=Path, default=None, metavar="FILE.gif",
                   help="also write a GIF for a README (--gif-fps, --gif-speed, --gif-width; default: none)")
    p.add_argument("--no-mp4", action="store_true", help="write only the GIF (with --gif)")
    p.add_argument("--fps", type=positive(240), default=25.0, help="frames per second of the MP4 (default: 25)")
    p.add_argument("--speed", type=positive(1000), default=1.0,
                   help="run seconds per video second (default: 1, real time)")
    p.add_argument("--size", type=_size, default=(960, 720), metavar="WxH",
                   help="MP4 frame size in pixels (default: 960x720)")
    p.add_argument("--gif-fps", type=positive(50), default=8.0, help="frames per second of the GIF (default: 8)")
    p.add_argument("--gif-speed", type=positive(1000), default=2.5,
                   help="run seconds per GIF second (default: 2.5)")
    p.add_argument("--gif-width", type=whole(64, 3840), default=480,
                   help="GIF width in pixels, height in the MP4's proportion (default: 480)")
    p.add_argument("--renderer", choices=("auto", "mujoco", "matplotlib"), default="auto",
                   help="auto: MuJoCo's offscreen renderer where it has an OpenGL context, else matplotlib "
                        "(default: auto)")
    p.add_argument("--spec", type=Path, default=None, metavar="FILE.toml",
                   help="the run's spec (TOML), when the folder's summary.json does not carry it and its recorded "
                        "path has moved (default: from summary.json)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no notes")
    args = p.parse_args(argv)
    if args.no_mp4 and args.gif is None:
        p.error("--no-mp4 leaves nothing to write: add --gif FILE")
    return args


@dataclass
class Loaded:
    method: str
    spec: object
    scene: Scene


def load(folder: Path, method: str | None = None, spec_file: Path | None = None) -> Loaded:
    """The folder's summary, spec and one method's scene (AnimationInputError when they cannot be had)."""
    summary = read_summary(folder)
    ran = methods_that_ran(summary, folder)
    if method is None:
        if not ran:
            raise AnimationInputError(f"no method in {folder / 'summary.json'} ran and left its CSV: nothing to "
                                      "animate; re-run `acroboter run`")
        method = ran[0]
    elif method not in ran:
        raise AnimationInputError(f"--method {method}: expected one of the methods that ran in {folder} "
                                  f"({', '.join(ran) or 'none'}), found '{method}'")
    spec = spec_of_run(summary, folder, spec_file)
    path = folder / f"{method}.csv"
    return Loaded(method, spec, build_scene(spec, read_columns(path), path))


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if not log.handlers:  # `python -m acroboter.animate`: the notes go where `acroboter animate` puts them
        from .cli import configure_logging

        configure_logging(0)
    level = log.level
    if args.quiet:
        log.setLevel(logging.WARNING)
    try:
        return _animate(args)
    except AnimationInputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except RendererUnavailable as err:
        print(f"error: {err}; --renderer matplotlib works everywhere", file=sys.stderr)
        return 3
    finally:
        log.setLevel(level)


def _animate(args: argparse.Namespace) -> int:
    data = load(args.results, args.method, args.spec)
    name, frames = choose_renderer(args.renderer, data.spec)
    written = []
    if not args.no_mp4:
        out = args.out or args.results / f"animation_{data.method}.mp4"
        rows = frame_rows(data.scene.t, args.fps, args.speed)
        start = time.perf_counter()
        count = _encode(write_mp4, frames(data.scene, data.spec, rows, args.size, data.method), out, args.fps,
                        len(rows), args.quiet)
        written.append(f"{out} ({count} frames, {args.size[0]}x{args.size[1]}, {time.perf_counter() - start:.1f} s)")
    if args.gif is not None:
        width = args.gif_width + args.gif_width % 2
        height = round(width * args.size[1] / args.size[0] / 2) * 2
        rows = frame_rows(data.scene.t, args.gif_fps, args.gif_speed)
        start = time.perf_counter()
        count = _encode(write_gif, frames(data.scene, data.spec, rows, (width, height), data.method), args.gif,
                        args.gif_fps, len(rows), args.quiet)
        written.append(f"{args.gif} ({count} frames, {width}x{height}, {args.gif.stat().st_size / 1e6:.2f} MB, "
                       f"{time.perf_counter() - start:.1f} s)")
    log.info(f"{data.method} drawn with {name}: " + "; ".join(written))
    return 0


def _encode(writer, frames, path: Path, fps: float, total: int, quiet: bool) -> int:
    """Write through a temporary name: an interrupted or failed render leaves no file that looks complete."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        count = writer(frames, partial, fps, total, quiet)
        os.replace(partial, path)
        return count
    finally:
        partial.unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
