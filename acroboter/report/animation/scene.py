"""Reading a results folder and the geometry of its frames, pure numpy (no drawing).

`load(folder)` reads summary.json, one method's CSV and the run's spec (its TOML text in the provenance, checked
against the recorded spec_sha256; else --spec, else the recorded path or the example of that name, each checked
against the recorded model hash), and
`build_scene` turns the CSV's pose columns q into every point a frame draws: the bodies' centres, axes and
points, the anchors (a moving one where the run recorded it), each cable's two ends, its tension and slack
flag, the outlines, fixed axes limits and the tension range. `frame_rows` picks the row each frame shows.
The colours both renderers share are named here too.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

AXES = ("u", "v", "w")
# The colours both renderers use (and the GIF palette keeps exact).
AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f77b4")  # u, v, w: red, green, blue
SLACK_COLOUR = "0.55"
TRACE_COLOUR = "#ff7f0e"
COLORMAP = "viridis"


class AnimationInputError(Exception):
    """The folder cannot be animated (bad input, exit 2): the message names the cause and the fix."""


# What a results folder's files may weigh before they are read (a 3 GB sparse CSV took 15.8 GB to load): a run's
# summary is kilobytes; its CSV at the cap of 360,000 control instants about 0.8 GB for the default crane.
MAX_SUMMARY_BYTES = 16 * 2**20
MAX_CSV_BYTES = 2**30


def _bounded(path: Path, limit: int) -> None:
    """AnimationInputError for a file larger than `limit` bytes (checked before it is read)."""
    try:
        size = path.stat().st_size
    except OSError:
        return  # missing or unreadable: the reader says so
    if size > limit:
        raise AnimationInputError(f"{path} is {size / 2**20:,.0f} MB, more than the {limit // 2**20:,} MB any "
                                  "`acroboter run` writes: it is not a run's record; re-run `acroboter run`")


# --- reading the folder ---------------------------------------------------------------------------


def read_summary(folder: Path) -> dict:
    if not folder.is_dir():
        what = "a file" if folder.exists() else "nothing"
        raise AnimationInputError(f"expected a results folder (as `acroboter run --out` writes), found {what} at "
                                  f"{folder}: give the folder that holds summary.json and the <method>.csv files")
    path = folder / "summary.json"
    _bounded(path, MAX_SUMMARY_BYTES)
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AnimationInputError(f"{folder} has no summary.json: give a folder written by `acroboter run`") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as err:
        why = "nested too deep" if isinstance(err, RecursionError) else err
        raise AnimationInputError(f"{path} is not valid JSON ({why}): re-run `acroboter run` to write it") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("methods", {}), dict):
        raise AnimationInputError(f"{path} is not a run's summary (expected an object with \"methods\"): re-run "
                                  "`acroboter run` to write it")
    return summary


def methods_that_ran(summary: dict, folder: Path) -> list[str]:
    """The methods of summary.json, in its order, that ran and left their CSV."""
    return [m for m, s in (summary.get("methods") or {}).items()
            if not (isinstance(s, dict) and "error" in s) and (folder / f"{m}.csv").is_file()]


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """A results CSV as {column: values}."""
    _bounded(path, MAX_CSV_BYTES)
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
    from ...model.spec import SpecError, parse_spec

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


def _recorded_spec(text: str, provenance: dict, summary: Path):
    """The spec from the provenance's TOML text, once the text is the one the run recorded: its SHA-256 is
    `spec_sha256` (the spec file's bytes), else (a folder without it) its model hash `spec_model_hash`."""
    fix = ("re-run `acroboter run` to write the folder again, or give the run's spec with --spec FILE (checked "
           "against the recorded model hash)")
    recorded, wanted = provenance.get("spec_sha256"), provenance.get("spec_model_hash")
    if isinstance(recorded, str):
        if hashlib.sha256(text.encode("utf-8")).hexdigest() != recorded:
            raise AnimationInputError(f"the spec text in {summary} (provenance: spec_toml) does not match the "
                                      "recorded spec_sha256: the summary was edited or is damaged, and drawing it "
                                      f"could show another crane; {fix}")
        return spec_from_toml(text, f"{summary} (provenance)")
    if not isinstance(wanted, str):
        raise AnimationInputError(f"the spec text in {summary} (provenance: spec_toml) has no recorded hash "
                                  f"(spec_sha256 or spec_model_hash) to check it against; {fix}")
    spec = spec_from_toml(text, f"{summary} (provenance)")
    if spec.model_hash() != wanted:
        raise AnimationInputError(f"the spec text in {summary} (provenance: spec_toml) is not the crane of the "
                                  f"recorded spec_model_hash: the summary was edited or is damaged; {fix}")
    return spec


def spec_of_run(summary: dict, folder: Path, override: Path | None = None):
    """The spec the run used: its TOML text in the provenance if there; else --spec; else the recorded path,
    else the example of that name, each only if its model (bodies, points, cables, anchors) is the run's."""
    from ...model.spec import load_spec
    from ...process.locations import example_spec

    provenance = summary.get("provenance") or {}
    wanted = provenance.get("spec_model_hash")
    text = _spec_text_in(provenance)
    if text is not None and override is None:
        return _recorded_spec(text, provenance, folder / "summary.json")
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
    diverged_at: float | None = None  # the run time at which the method diverged (its CSV stops there)


def body_point(centre: np.ndarray, axes: np.ndarray, xi) -> np.ndarray:
    """p = r + ξ1 u + ξ2 v + ξ3 w for every row: centre (N, 3), axes (N, 3, 3) rows u, v, w."""
    return centre + np.einsum("k,nkj->nj", np.asarray(xi, dtype=float), axes)


def _column(columns: dict[str, np.ndarray], name: str, path: Path | None) -> np.ndarray:
    try:
        values = columns[name]
    except KeyError:
        where = f"{path} has" if path is not None else "the columns have"
        raise AnimationInputError(
            f"{where} no column {name}: the pose (q_<body>.r_x_m, ..., q_<body>.w_z) and the moving anchors "
            "(anchor_<name>_x_m, ...) are needed to draw the crane; results written before acroboter recorded them "
            "lack them: re-run `acroboter run` to write them") from None
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:  # a run records finite poses only (a diverged one stops before): this is not a run's record
        where = f"{path}, line {bad[0] + 2}" if path is not None else f"row {bad[0] + 1}"
        raise AnimationInputError(f"{where}: {name} is {values[bad[0]]}, not a pose a run records: re-run "
                                  "`acroboter run` to write it")
    return values


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



# --- one method's run ------------------------------------------------------------------------


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
    scene = build_scene(spec, read_columns(path), path)
    figures = (summary.get("methods") or {}).get(method)
    diverged = figures.get("diverged_at_s") if isinstance(figures, dict) else None
    scene.diverged_at = float(diverged) if isinstance(diverged, (int, float)) else None
    return Loaded(method, spec, scene)


def diverged_note(scene: Scene) -> str | None:
    """What the last frames of a diverged method say (its video stops there, short of the scenario's end)."""
    return None if scene.diverged_at is None else f"diverged at t = {scene.diverged_at:.2f} s"
