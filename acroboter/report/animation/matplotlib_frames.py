"""The matplotlib renderer: a frame of the scene at any row as an RGB array, on matplotlib's Agg canvas.

Works everywhere, no display needed: the figure has its own canvas (the user's pyplot backend and figures are
left alone), the artists are made once, the static part is drawn once and kept as a bitmap, and each frame
restores it and draws only the moving artists, whose data are updated in place.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from .scene import AXIS_COLOURS, COLORMAP, SLACK_COLOUR, TRACE_COLOUR, Scene, diverged_note, outline_xyz

BASE_WIDTH_IN = 6.4  # the figure's width in inches: --size sets the dpi, so the layout is the same at every size


class MatplotlibFrames:
    """Draws the scene at any row into an RGB array. The static part (axes, ceiling, fixed anchors, desired
    path, colorbar) is drawn once and kept as a bitmap; per frame only the moving artists are drawn on it."""

    def __init__(self, scene: Scene, method: str, size: tuple[int, int]):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.scene, self.size = scene, size
        width, height = size
        dpi = width / BASE_WIDTH_IN
        self.fig = fig = Figure(figsize=(BASE_WIDTH_IN, height / dpi), dpi=dpi)
        self.canvas = FigureCanvasAgg(fig)
        self.ax = self._crane_view()
        self._tension_bar()
        self.top = self._top_view()
        self._moving_artists(method)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)

    def _crane_view(self):
        """The 3-D axes at equal scale, with the static scene: the ceiling, the fixed anchors, the desired path."""
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        scene = self.scene
        ax = self.fig.add_axes((-0.04, 0.03, 0.66, 0.93), projection="3d")
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
        return ax

    def _tension_bar(self) -> None:
        from matplotlib import colormaps
        from matplotlib.cm import ScalarMappable
        from matplotlib.colors import Normalize

        fig = self.fig
        self.norm = Normalize(*self.scene.tension_range)
        self.cmap = colormaps[COLORMAP]
        bar = fig.colorbar(ScalarMappable(norm=self.norm, cmap=self.cmap), cax=fig.add_axes((0.64, 0.16, 0.32, 0.025)),
                           orientation="horizontal")
        bar.set_label("cable tension [N] (dashed grey: slack)", fontsize=7)
        bar.ax.tick_params(labelsize=6)

    def _top_view(self):
        """The tracked point from above, zoomed on its path (the 3-D view shows the whole crane)."""
        scene = self.scene
        top = self.fig.add_axes((0.66, 0.36, 0.30, 0.50))
        span = np.concatenate([scene.desired, scene.tracked])[:, :2]
        span = span[np.all(np.isfinite(span), axis=1)]
        centre, half = (span.min(0) + span.max(0)) / 2, max(float(np.ptp(span, axis=0).max()) * 0.6, 0.01)
        top.set_xlim(centre[0] - half, centre[0] + half)
        top.set_ylim(centre[1] - half, centre[1] + half)
        top.set_aspect("equal")
        top.plot(scene.desired[:, 0], scene.desired[:, 1], color="0.35", lw=0.6, ls=":")
        top.set_title("tracked point, from above", fontsize=7)
        top.set_xlabel("x [m]", fontsize=6, labelpad=1)
        top.set_ylabel("y [m]", fontsize=6, labelpad=1)
        top.tick_params(labelsize=5)
        top.grid(alpha=0.3)
        return top

    def _moving_artists(self, method: str) -> None:
        """The artists each frame redraws on the static bitmap, and the method's name."""
        scene, ax, top, fig = self.scene, self.ax, self.top, self.fig
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
        # "diverged at t = 2.12 s" on a diverged method's last frames (render(..., note=True))
        self.note = fig.text(0.31, 0.88, diverged_note(scene) or "", fontsize=10, ha="center", weight="bold",
                             color=AXIS_COLOURS[0], animated=True)
        self.moving_artists = [self.trace, self.tracked, self.moving, *self.cable_lines, *self.outlines.values(),
                               *(a for lines in self.axis_lines.values() for a in lines)]

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

    def render(self, row: int, note: bool = False) -> np.ndarray:
        """The frame at `row` as an (H, W, 3) uint8 array; `note`: with the divergence note (if the run diverged)."""
        self.update(row)
        self.canvas.restore_region(self.background)
        for artist in self.moving_artists:
            self.ax.draw_artist(artist)
        self.top.draw_artist(self.top_trace)
        self.top.draw_artist(self.top_point)
        self.fig.draw_artist(self.clock)
        if note and self.note.get_text():
            self.fig.draw_artist(self.note)
        return np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()


def render_rows(scene: Scene, spec, rows: np.ndarray, size: tuple[int, int], method: str,
                note_from: int | None = None) -> Iterator[np.ndarray]:
    """The frames of `rows`, one at a time (the frame generator choose_renderer hands out); frames from index
    `note_from` on carry the divergence note (a diverged run's last frames)."""
    frames = MatplotlibFrames(scene, method, size)
    for k, row in enumerate(rows):
        yield frames.render(int(row), note=note_from is not None and k >= note_from)


def drawing_colours(samples: int = 48) -> list[tuple[int, int, int]]:
    """The colours the moving artists use (axes, trace, slack, outline, the tension colormap): kept exact in a
    GIF's palette even when the first frame does not show them yet."""
    from matplotlib import colormaps
    from matplotlib.colors import to_rgb

    rgb = [to_rgb(c) for c in (*AXIS_COLOURS, TRACE_COLOUR, SLACK_COLOUR, "0.15", "k", "w")]
    rgb += [colormaps[COLORMAP](x)[:3] for x in np.linspace(0, 1, samples)]
    return [tuple(round(255 * v) for v in c) for c in rgb]
