"""`acroboter animate RESULTS_DIR`: a video of one method's run, drawn from its results folder alone.

    python -m acroboter.animate results                      # results/animation_<first method>.mp4
    acroboter animate results --method penalty --gif docs/run/acroboter.gif

Every frame: the ceiling at the height of the highest anchor, the anchors (a moving one where the
run recorded it), each cable from end to end coloured by its tension (one colour scale over the whole
run, dashed grey while slack), both bodies with their axes u, v, w (red, green, blue) and an outline
through their points, the desired path and the tracked point's trace so far, the time and the method.

This module is the command line: the options, the choice of renderer and the order of the work. The work is
in acroboter/animation/: `scene` reads the folder (the CSV's pose columns q and the run's spec) and computes
every drawn point (pure numpy), `matplotlib_frames` and `mujoco_frames` draw frames, `encode` writes the MP4
(imageio's ffmpeg) and the GIF (Pillow). `--renderer auto` uses MuJoCo's offscreen renderer (the crane's MJCF
model) where it has an OpenGL context (EGL or OSMesa), else matplotlib, and says which and why
(docs/animation.md). The MP4 needs the animation extra, --renderer mujoco the mujoco extra (docs/extras.md);
a GIF drawn with matplotlib needs only the core.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import time
from functools import partial
from pathlib import Path

from ..model.ranges import FPS, GIF_FPS, GIF_SPEED, GIF_WIDTH, HEIGHT, SPEED, WIDTH, frames_problem
from ..process.extras import require
from ..report.animation import matplotlib_frames, mujoco_frames
from ..report.animation.encode import write_complete, write_gif, write_mp4
from ..report.animation.mujoco_frames import GL_FIX, RendererUnavailable, mujoco_ready, probe_gl
from ..report.animation.scene import AnimationInputError, diverged_note, frame_rows, load
from .entry import carrying, file_write_problem, folder_write_problem, guarded, ranged
from .outputs import out_path, results_folder

log = logging.getLogger("acroboter")

GIF_WIDTH_MAX = GIF_WIDTH.high  # write_gif holds every frame (W x H bytes each) until it saves: 1920x1440 is 2.8 MB
NOTE_SECONDS = 2.0  # a diverged method's note stays on the video's last 2 s


def _frames(count: int) -> str:
    return f"{count} frame{'' if count == 1 else 's'}"


def choose_renderer(requested: str, spec):
    """(name, frame generator) for --renderer; `auto`: MuJoCo where it has a GL context and can draw the spec,
    else matplotlib, with one log line saying which and why."""
    if requested == "matplotlib":
        return "matplotlib", matplotlib_frames.render_rows
    backend, why = probe_gl()
    if backend is not None:
        try:
            mujoco_ready(spec)
        except RendererUnavailable as err:
            why = f"{why}, but {err}"
        else:
            os.environ["MUJOCO_GL"] = backend
            log.info(f"renderer: mujoco ({why})")
            return "mujoco", mujoco_frames.render_rows
        if requested == "mujoco":
            raise RendererUnavailable(f"--renderer mujoco cannot run here: {why}")
    elif requested == "mujoco":
        raise RendererUnavailable(f"--renderer mujoco cannot run here ({why}): {GL_FIX}")
    log.info(f"renderer: matplotlib (MuJoCo's is not usable here: {why})")
    return "matplotlib", matplotlib_frames.render_rows


# --- the command line -----------------------------------------------------------------------------


def _size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, each in its range (acroboter.model.ranges: WIDTH, HEIGHT)."""
    parts = str(text).lower().split("x")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels such as 960x720 with {WIDTH.text()} and "
                                         f"{HEIGHT.text()}, found '{text}'")
    try:
        w, h = WIDTH.parse(parts[0]), HEIGHT.parse(parts[1])
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text}: {err}") from None
    return w + w % 2, h + h % 2  # H.264 in yuv420p needs even sizes: an odd one grows by a pixel


carrying(_size, "size", (WIDTH, HEIGHT), "{}x720")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="acroboter animate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", type=out_path, metavar="RESULTS_DIR", help="a folder written by `acroboter run --out`")
    p.add_argument("--method", default=None, help="the method to show (default: the first in summary.json that ran)")
    p.add_argument("--out", type=out_path, default=None, metavar="FILE.mp4",
                   help="the MP4 to write, or an existing folder for FOLDER/animation_<method>.mp4 "
                        "(default: RESULTS_DIR/animation_<method>.mp4)")
    p.add_argument("--gif", type=out_path, default=None, metavar="FILE.gif",
                   help="also write a GIF for a README, or into an existing folder as FOLDER/animation_<method>.gif "
                        "(--gif-fps, --gif-speed, --gif-width; default: none)")
    p.add_argument("--no-mp4", action="store_true", help="write only the GIF (with --gif)")
    p.add_argument("--fps", type=ranged(FPS), default=25.0,
                   help="frames per second of the MP4, 0.01..240 (default: 25)")
    p.add_argument("--speed", type=ranged(SPEED), default=1.0,
                   help="run seconds per video second, 0.001..1000, at most 200,000 frames (default: 1, real time)")
    p.add_argument("--size", type=_size, default=(960, 720), metavar="WxH",
                   help="MP4 frame size in pixels (default: 960x720)")
    p.add_argument("--gif-fps", type=ranged(GIF_FPS), default=8.0,
                   help="frames per second of the GIF, 0.01..50 (default: 8)")
    p.add_argument("--gif-speed", type=ranged(GIF_SPEED), default=2.5,
                   help="run seconds per GIF second, 0.001..1000, at most 1 GB of frames held (default: 2.5)")
    p.add_argument("--gif-width", type=ranged(GIF_WIDTH), default=480,
                   help=f"GIF width in pixels (at most {GIF_WIDTH_MAX}), height in the MP4's proportion (default: 480)")
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
    if not args.no_mp4:  # the outputs' folders, before any work (the default: into RESULTS_DIR, when it is one)
        if args.out is not None:
            check_output(p, args.out, "--out", ".mp4", "for a GIF use --gif FILE.gif (with --no-mp4 for the GIF alone)")
        elif args.results.is_dir() and (problem := folder_write_problem(args.results)):
            p.error(f"RESULTS_DIR {args.results} (where the MP4 goes by default): {problem}; or give --out FILE.mp4 "
                    "elsewhere")
    if args.gif is not None:
        check_output(p, args.gif, "--gif", ".gif", "for an MP4 use --out FILE.mp4")
    # the options checked, the extras they need (MissingExtraError: one line with the `pip install`, exit 2);
    # --renderer auto without mujoco draws with matplotlib, and a GIF needs only the core
    if not args.no_mp4:
        require("animation", "an MP4", "a GIF alone needs no extra: --no-mp4 --gif FILE.gif")
    if args.renderer == "mujoco":
        require("mujoco", "--renderer mujoco", "--renderer matplotlib needs no extra")
    return args


def check_output(p: argparse.ArgumentParser, path: Path, option: str, suffix: str, other: str) -> None:
    """An output (--out, --gif): an existing folder (it gets animation_<method><suffix>) or a file name ending in
    `suffix` in an existing, writable folder, none created (parser.error: exit 2 before any work)."""
    if path.is_dir():
        problem = folder_write_problem(path)
        if problem:
            p.error(f"{option} {path}: {problem}; give a folder you can write to")
        return
    if path.suffix.lower() != suffix:
        p.error(f"{option} {path}: expected a file name ending in {suffix} or an existing folder, found "
                f"{'no extension' if not path.suffix else repr(path.suffix)}; {other}")
    problem = file_write_problem(path)
    if problem:
        p.error(f"{option} {path}: {problem}; give a path in an existing folder you can write to")


@guarded
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if not log.handlers:  # `python -m acroboter.animate`: the notes go where `acroboter animate` puts them
        from .console import configure_logging

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


def _gif_size(args: argparse.Namespace) -> tuple[int, int]:
    width = args.gif_width + args.gif_width % 2
    return width, round(width * args.size[1] / args.size[0] / 2) * 2


def check_frames(args: argparse.Namespace, duration: float) -> None:
    """The frames (and, for the GIF, the memory its writer holds) of a `duration` s run, counted before any frame is
    drawn: too many is an AnimationInputError (exit 2) with --speed's range for this run."""
    if not args.no_mp4 and (problem := frames_problem(duration, args.fps, args.speed, SPEED)) is not None:
        raise AnimationInputError(f"--speed: {problem}; or lower --fps")
    if args.gif is not None:
        width, height = _gif_size(args)
        if (problem := frames_problem(duration, args.gif_fps, args.gif_speed, GIF_SPEED, width * height)) is not None:
            raise AnimationInputError(f"--gif-speed: {problem}; or lower --gif-fps or --gif-width")


def _animate(args: argparse.Namespace) -> int:
    data = load(args.results, args.method, args.spec)
    check_frames(args, float(data.scene.t[-1] - data.scene.t[0]))
    name, frames = choose_renderer(args.renderer, data.spec)
    note = diverged_note(data.scene)

    def note_from(rows, fps: float) -> int | None:  # a diverged run's note on the video's last NOTE_SECONDS
        return None if note is None else max(0, len(rows) - max(1, round(NOTE_SECONDS * fps)))

    written = []
    # Into a folder, the video is animation_<method>.<ext>, written under the output-folder contract (docs/run.md):
    # the folder locked, the video staged and swapped in, recorded in its manifest (the next animate, or the next
    # run into a run folder, replaces it); a file of that name the manifest does not list is the user's: refused
    # (exit 2) before any frame is drawn. A file named by --out or --gif is written through a temporary name.
    mp4 = gif_out = None
    if not args.no_mp4:
        mp4 = args.out if args.out is not None else args.results
        mp4_option = "--out" if args.out is not None else "RESULTS_DIR"
        mp4 = mp4 / f"animation_{data.method}.mp4" if mp4.is_dir() else mp4
    if args.gif is not None:
        gif_out = args.gif / f"animation_{data.method}.gif" if args.gif.is_dir() else args.gif
    into_folder = {}  # a video's path -> (its folder, the option that named it)
    if mp4 is not None and mp4 != args.out:
        into_folder[mp4] = (mp4.parent, mp4_option)
    if gif_out is not None and gif_out != args.gif:
        into_folder[gif_out] = (gif_out.parent, "--gif")
    with contextlib.ExitStack() as stack:
        staged = {}  # a folder (resolved) -> its ResultsFolder
        for folder, option in into_folder.values():
            key = folder.resolve()
            if key not in staged:
                names = [p.name for p, (f, _) in into_folder.items() if f.resolve() == key]
                staged[key] = stack.enter_context(results_folder(folder, "animate", option=option, expected=names,
                                                                 accumulate=True))

        def where(path: Path) -> Path:  # where a video is written now: its folder's staging, or the file itself
            folder = staged.get(path.parent.resolve()) if path in into_folder else None
            return path if folder is None else folder.staging / path.name

        if mp4 is not None:
            rows = frame_rows(data.scene.t, args.fps, args.speed)
            start = time.perf_counter()
            count = write_complete(write_mp4, frames(data.scene, data.spec, rows, args.size, data.method,
                                                     note_from(rows, args.fps)), where(mp4), args.fps, len(rows),
                                   args.quiet)
            written.append(f"{mp4} ({_frames(count)}, {args.size[0]}x{args.size[1]}, "
                           f"{time.perf_counter() - start:.1f} s)")
        if gif_out is not None:
            width, height = _gif_size(args)
            rows = frame_rows(data.scene.t, args.gif_fps, args.gif_speed)
            start = time.perf_counter()
            # one palette for either renderer's frames: the first frame's colours and the drawing's own, kept exact
            gif = partial(write_gif, keep=matplotlib_frames.drawing_colours())
            count = write_complete(gif, frames(data.scene, data.spec, rows, (width, height), data.method,
                                               note_from(rows, args.gif_fps)), where(gif_out), args.gif_fps,
                                   len(rows), args.quiet)
            size = where(gif_out).stat().st_size
            written.append(f"{gif_out} ({_frames(count)}, {width}x{height}, {size / 1e6:.2f} MB, "
                           f"{time.perf_counter() - start:.1f} s)")
        for folder in staged.values():  # every video drawn: swapped in together
            folder.publish()
    stops = "" if note is None else f" (it {note}: the video stops there, short of the scenario's end)"
    log.info(f"{data.method} drawn with {name}{stops}: " + "; ".join(written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
