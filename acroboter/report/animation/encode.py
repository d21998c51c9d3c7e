"""Writing frames to a video file: MP4 (imageio's ffmpeg, H.264 in yuv420p: the animation extra) and GIF (Pillow,
one palette: the core).

Each writer takes an iterator of (H, W, 3) uint8 frames and returns how many it wrote; `write_complete` runs one
through a temporary name, so an interrupted or failed render leaves no file that looks complete. Independent of
what the frames show: the colours a GIF's palette must keep exact are passed in (`keep`).
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

import numpy as np

from ...runtime.progress import progress_disabled


def write_mp4(frames: Iterator[np.ndarray], path: Path, fps: float, total: int, quiet: bool) -> int:
    """H.264 in yuv420p (plays everywhere); even frame sizes, so no resizing. Returns the frame count. Needs the
    animation extra (imageio and its ffmpeg): MissingExtraError without it."""
    from ...process.extras import require

    require("animation", "an MP4", "a GIF needs no extra")
    import imageio.v2 as imageio
    from tqdm import tqdm

    count = 0
    # ffmpeg's own lines at -v only: a Ctrl-C that lands inside imageio's writer ends its generator, which closes
    # ffmpeg's input mid-frame before it can be killed, and ffmpeg's "Invalid buffer size" is no news to a user
    # who pressed Ctrl-C; a real failure still raises imageio's error with ffmpeg's exit code
    level = "error" if logging.getLogger("acroboter").isEnabledFor(logging.DEBUG) else "fatal"
    writer = imageio.get_writer(path, fps=fps, codec="libx264", quality=7, pixelformat="yuv420p",
                                macro_block_size=2, ffmpeg_log_level=level)
    try:
        for frame in tqdm(frames, total=total, unit="frame", desc=f"rendering {path.name}",
                          disable=progress_disabled(quiet), file=sys.stderr):
            writer.append_data(frame)
            count += 1
    except BaseException:  # Ctrl-C or an error: the video is abandoned
        _abandon(writer)
        raise
    writer.close()
    return count


def _abandon(writer) -> None:
    """Stop an MP4 writer's ffmpeg at once: killed before its input closes (closed, it would print its complaint
    about a half frame on the terminal, and the writer would wait for it), then the writer closed."""
    frame = getattr(getattr(writer, "_write_gen", None), "gi_frame", None)  # imageio-ffmpeg's write_frames
    ffmpeg = frame.f_locals.get("p") if frame is not None else None
    if ffmpeg is not None and hasattr(ffmpeg, "kill") and ffmpeg.poll() is None:
        ffmpeg.kill()
        ffmpeg.wait()
    try:
        writer.close()
    except Exception:  # noqa: BLE001 - abandoned: the error that stopped it is the one to report
        pass


def write_gif(frames: Iterator[np.ndarray], path: Path, fps: float, total: int, quiet: bool,
              keep: Sequence[tuple[int, int, int]] = ()) -> int:
    """A looping GIF with one palette (the first frame's colours and `keep`, the drawing's own) and no dithering:
    the static background stays identical between frames, and Pillow stores only each frame's changed rectangle."""
    from PIL import Image
    from tqdm import tqdm

    images, palette = [], None
    for frame in tqdm(frames, total=total, unit="frame", desc=f"rendering {path.name}",
                      disable=progress_disabled(quiet), file=sys.stderr):
        image = Image.fromarray(frame)
        if palette is None:
            own = [tuple(c) for c in keep]
            first = image.quantize(colors=256 - len(own), method=Image.Quantize.MEDIANCUT).getpalette()
            palette = Image.new("P", (1, 1))
            palette.putpalette([*first[: 3 * (256 - len(own))], *(v for c in own for v in c)])
        images.append(image.quantize(palette=palette, dither=Image.Dither.NONE))
    images[0].save(path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0,
                   optimize=False, disposal=1)
    return len(images)


def write_complete(writer, frames: Iterable[np.ndarray], path: Path, fps: float, total: int, quiet: bool) -> int:
    """Write through a temporary name of this process (.<stem>.<pid>.partial<suffix>): an interrupted or failed
    render leaves no file that looks complete, two renders of one file never write into each other's, and one
    that a killed render left is removed by the next render of the same file. The folder must exist (the
    command line checks it before any work): none is created."""
    for stale in path.parent.glob(f".{path.stem}.*.partial{path.suffix}"):
        pid = stale.name[len(path.stem) + 2:-len(".partial" + path.suffix)]
        if pid.isdigit() and not _alive(int(pid)):
            stale.unlink(missing_ok=True)
    partial = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    try:
        count = writer(frames, partial, fps, total, quiet)
        os.replace(partial, path)
        return count
    finally:
        partial.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True
