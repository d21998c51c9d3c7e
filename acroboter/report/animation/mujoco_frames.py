"""The MuJoCo renderer: a frame of the scene at any row from MuJoCo's offscreen renderer.

`probe_gl` finds a MUJOCO_GL value that gives an OpenGL context without a display (EGL or OSMesa, tried in a
subprocess), `mujoco_ready` checks that the spec's MJCF model builds, `camera_pose` fits a fixed camera to the
run, and `MujocoFrames` poses the crane's MJCF model from each row's q and draws it, with the axes, outlines,
path and trace added to MuJoCo's scene and the clock, colour bar and top view drawn onto the image (Pillow).
mujoco is imported only inside functions: it picks its GL backend from MUJOCO_GL once, when first imported.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from collections.abc import Iterator

import numpy as np

from .scene import AXIS_COLOURS, COLORMAP, Scene, diverged_note, outline_xyz


class RendererUnavailable(Exception):
    """A renderer cannot run here (no OpenGL context, no model): `auto` falls back to matplotlib."""


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
AXIS_RGBA = tuple((*(int(c[i : i + 2], 16) / 255 for i in (1, 3, 5)), 1.0) for c in AXIS_COLOURS)
NOTE_RGB = tuple(int(AXIS_COLOURS[0][i : i + 2], 16) for i in (1, 3, 5))  # the divergence note: the u axis' red
CABLE_EMISSION = 0.4  # the cables' tendons lit flat (MuJoCo's emission): the colormap's colour, not shaded darker
PANEL_RGB = (38, 38, 42)  # the colour bar's and the top view's background (MuJoCo's is black)
BODY_ALPHA = 0.3  # the bodies' discs, see-through: the axes inside them show
PATH_POINTS = 400  # the desired path and the trace are drawn through at most this many rows each
VIEW_SHARE = 0.6  # of the image's width that holds the crane
AZIMUTH, ELEVATION = 125.0, -18.0  # the camera: the matplotlib view (azim -55, elev 18) in MuJoCo's convention


def probe_gl(timeout: float = 60.0) -> tuple[str | None, str]:
    """(MUJOCO_GL value that works, why) by creating a tiny mujoco.Renderer in a subprocess (a failing GL
    library can abort the process; this one stays clean). MUJOCO_GL from the environment is tried alone.
    mujoco is not imported here: it picks its GL backend from MUJOCO_GL once, when first imported."""
    from ...process.extras import install_line, missing

    if missing("mujoco") is not None:
        return None, f"mujoco is not installed ({install_line('mujoco')})"
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
    imported: where it was imported before (by another part of the program), its context class is replaced.
    Without the mujoco extra: MissingExtraError."""
    from ...process.extras import require

    require("mujoco", "the MuJoCo renderer", "the matplotlib renderer needs no extra")
    backend = os.environ.setdefault("MUJOCO_GL", "egl")
    if backend == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    import importlib

    import mujoco
    from mujoco import gl_context

    if backend in ("egl", "osmesa") and getattr(gl_context, "_MUJOCO_GL", backend) != backend:
        gl_context.GLContext = importlib.import_module(f"mujoco.{backend}").GLContext
    return mujoco


def mujoco_ready(spec) -> None:
    """Raise RendererUnavailable unless the MuJoCo backend can draw this spec: its MJCF model must build."""
    from ...model.mjcf_model import mjcf_xml
    from ...model.spec import SpecError

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
    (acroboter.model.mjcf_model) posed from the row's q by MujocoPlant.set_state, the moving anchors where the run
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

        from ...model.layout import build_layout
        from ...sim.mujoco_plant import MujocoPlant

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
        # at least a pixel's radius at the look-at distance: thinner, a small image draws the cables dotted
        self.cable_width = max(self.cable_width, distance * math.tan(math.radians(fovy) / 2) * 2 / height)
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

    def render(self, row: int, note: bool = False) -> np.ndarray:
        """The frame at `row` as an (H, W, 3) uint8 array; `note`: with the divergence note (if the run diverged)."""
        mj, s = self.mj, self.scene
        self.update(row)
        r = self.renderer
        r.update_scene(self.data, camera=self.camera, scene_option=self.option)
        r.scene.flags[mj.mjtRndFlag.mjRND_SHADOW] = 0
        r.scene.flags[mj.mjtRndFlag.mjRND_REFLECTION] = 0
        for g in r.scene.geoms[: r.scene.ngeom]:  # the cables lit flat: their colour is the colormap's, unshaded
            if g.objtype == mj.mjtObj.mjOBJ_TENDON:
                g.emission, g.specular = CABLE_EMISSION, 0.0
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
        self._overlay(frame, row, note)
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

    def _overlay(self, frame: np.ndarray, row: int, note: bool = False) -> None:
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
        text = diverged_note(self.scene)
        if note and text:  # a diverged run's last frames: below the clock, over the crane's view
            image = Image.fromarray(frame)
            draw = ImageDraw.Draw(image)
            at = (round(VIEW_SHARE * self.size[0] / 2), self.band + pad)
            box = draw.textbbox(at, text, font=self.font, anchor="ma")
            draw.rectangle((box[0] - pad, box[1] - pad, box[2] + pad, box[3] + pad), fill=PANEL_RGB)
            draw.text(at, text, fill=NOTE_RGB, font=self.font, anchor="ma")
            frame[:] = np.asarray(image)

    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None


def render_rows(scene: Scene, spec, rows: np.ndarray, size: tuple[int, int], method: str,
                note_from: int | None = None) -> Iterator[np.ndarray]:
    """The frames of `rows`, one at a time (the frame generator choose_renderer hands out); frames from index
    `note_from` on carry the divergence note (a diverged run's last frames). The GL context is released when
    the generator ends or is closed."""
    frames = MujocoFrames(scene, spec, method, size)
    try:
        for k, row in enumerate(rows):
            yield frames.render(int(row), note=note_from is not None and k >= note_from)
    finally:
        frames.close()
