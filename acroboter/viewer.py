"""`acroboter run --view`: replay a run in MuJoCo's interactive viewer (needs a display).

The recorded natural coordinates of each method are set into the spec's MJCF model instant by
instant (acroboter.mujoco_plant.MujocoPlant.set_state), in real time, whichever plant simulated
them; close the window to go on. Without a display `display_problem()` says why, before any work.
"""

from __future__ import annotations

import os
import sys
import time


def display_problem() -> str | None:
    """Why no window can open here (None: a display is there)."""
    if sys.platform in ("darwin", "win32"):
        return None
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    return ("--view opens MuJoCo's interactive viewer, which needs a display, and neither DISPLAY nor "
            "WAYLAND_DISPLAY is set here: leave out --view (the results folder has the figures), make a "
            "video with `acroboter animate RESULTS_DIR`, or run under a desktop or `xvfb-run`")


def replay(model, path, results: dict, speed: float = 1.0) -> None:
    """Show each method's run (name -> acroboter.result.Result) in turn in one viewer window."""
    import mujoco.viewer

    from .mujoco_plant import MujocoPlant

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
