"""`acroboter run --view`: replay a run in MuJoCo's interactive viewer (needs a display).

The recorded natural coordinates of each method are set into the spec's MJCF model instant by
instant (acroboter.sim.mujoco_plant.MujocoPlant.set_state), in real time, whichever plant simulated
them; close the window to go on. It needs the mujoco extra (checked with the options, acroboter.cli.run_args).
Without a display `display_problem()` says why, before any work.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

FIX = ("leave out --view (the results folder has the figures), make a video with `acroboter animate "
       "RESULTS_DIR`, or run under a desktop or `xvfb-run`")


def display_problem() -> str | None:
    """Why no window can open here (None: a display is there): no DISPLAY or WAYLAND_DISPLAY, or one
    that GLFW (the viewer's windowing library) cannot open, tried in a subprocess."""
    if sys.platform not in ("darwin", "win32") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return ("--view opens MuJoCo's interactive viewer, which needs a display, and neither DISPLAY nor "
                f"WAYLAND_DISPLAY is set here: {FIX}")
    probe = "import glfw, sys; ok = glfw.init(); glfw.terminate(); sys.exit(0 if ok else 1)"
    try:
        done = subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=30)
    except subprocess.TimeoutExpired:
        done = None
    if done is None or done.returncode != 0:
        shown = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY") or "the desktop"
        return f"--view opens MuJoCo's interactive viewer, but GLFW could not open a window on {shown}: {FIX}"
    return None


def replay(model, path, results: dict, speed: float = 1.0) -> None:
    """Show each method's run (name -> acroboter.sim.result.Result) in turn in one viewer window (the mujoco
    extra: MissingExtraError without it)."""
    from ..process.extras import require

    require("mujoco", "MuJoCo's viewer")
    import mujoco.viewer

    from ..sim.mujoco_plant import MujocoPlant

    plant = MujocoPlant(model, path)
    with mujoco.viewer.launch_passive(plant.mj_model, plant.mj_data) as view:
        for name, result in results.items():
            print(f"viewer: {name} ({result.time[-1]:.1f} s); close the window to stop", file=sys.stderr)
            wall0 = time.perf_counter()
            for k, t in enumerate(result.time):
                if not view.is_running():
                    return
                plant.set_state(result.q[k], result.qd[k], float(t))
                view.sync()
                lag = t / speed - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)
        while view.is_running():  # the last pose stays until the window is closed
            time.sleep(0.05)
