"""What a simulation returns: named, unit-labelled time series with a summary, a table and a plot.

    result = crane.simulate("penalty", duration=10.0)
    result.time                      # s
    result.position_error_mm         # |σ_position| at each control instant
    result.input("tension_1")        # N, by actuator name
    result.coordinate("SU.r_z")      # m, by coordinate name (result.velocity(...) for q̇)
    result.summary()                 # the figures of summary.json for this method
    result.to_csv("penalty.csv")     # the CSV the `run` command writes
    result.to_dataframe()            # pandas, if installed
    result.plot()                    # errors and inputs against time (matplotlib Figure)
"""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from ..model.layout import Layout
from .records import RunResult, Scenario, position_error_mm, realized_yaw, summarize, tilt_deg


def _unit_suffix(unit: str) -> str:
    """'N' -> 'N', 'N·m' -> 'Nm': units that fit in a CSV column name."""
    return unit.replace("·", "").replace("/", "per")


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.]+", "_", name).strip("_")


class Result:
    """One method's closed-loop run on one crane (python-control's response objects are the model).

    Arrays are indexed by control instant (rows) and, where there are several, by the names in
    `coordinates`, `inputs`, `cables`, `servo_constraints` (columns)."""

    def __init__(self, run: RunResult, layout: Layout, scenario: Scenario, spec_name: str):
        self.run, self.layout, self.scenario, self.spec_name = run, layout, scenario, spec_name
        self.method: str = run.method
        self.coordinates: list[str] = list(layout.coordinates)
        self.inputs: list[str] = list(layout.inputs)
        self.input_units: list[str] = list(layout.input_units)
        self.cables: list[str] = list(run.cable_names)
        self.servo_constraints: list[str] = list(layout.servo_constraints)
        self._summary: dict | None = None

    # --- arrays ---------------------------------------------------------------------------------
    @property
    def time(self) -> np.ndarray:
        """Control instants, s."""
        return self.run.t

    @property
    def q(self) -> np.ndarray:
        """Natural coordinates at each instant (columns: `coordinates`; m for r_*, unit vectors else)."""
        return self.run.q

    @property
    def qd(self) -> np.ndarray:
        return self.run.qd

    @property
    def u(self) -> np.ndarray:
        """Inputs at each instant, held over the control period that follows (columns: `inputs`)."""
        return self.run.u

    @property
    def position(self) -> np.ndarray:
        """The tracked point, m (N x 3)."""
        return self.run.sigma[:, self.scenario.position_rows] + self.run.desired[:, :3]

    @property
    def desired_position(self) -> np.ndarray:
        return self.run.desired[:, :3]

    @property
    def position_error_mm(self) -> np.ndarray:
        """|realized − desired position| of the tracked point, mm."""
        return position_error_mm(self.run, self.scenario)

    @property
    def yaw_deg(self) -> np.ndarray:
        """Yaw of the task's yaw body (unwrapped), deg."""
        return np.degrees(realized_yaw(self.run, self.scenario))

    @property
    def desired_yaw_deg(self) -> np.ndarray:
        return np.degrees(self.run.desired[:, 3])

    @property
    def yaw_error_deg(self) -> np.ndarray | None:
        """Realized − desired yaw, wrapped to ±180 deg (None: the crane has no yaw task)."""
        if self.scenario.yaw_body_offset is None:
            return None
        # Through yaw_deg (the CSV's column), so that the two columns agree to the bit as recorded.
        err = np.radians(self.yaw_deg) - self.run.desired[:, 3]
        return np.degrees(np.angle(np.exp(1j * err)))

    @property
    def tilt_deg(self) -> np.ndarray:
        """Angle of the tracked body's w axis from the vertical, deg."""
        return tilt_deg(self.run, self.scenario)

    @property
    def cable_tension(self) -> np.ndarray:
        """The plant's cable tensions, N (columns: `cables`), at the start of the step after each instant."""
        return self.run.cable_tension

    @property
    def saturated(self) -> np.ndarray:
        """Per instant: a limit kept the input from what the controller asked of the task."""
        return self.run.saturated

    @property
    def diverged_at(self) -> float | None:
        return self.run.diverged_at

    # --- what the controller saw (runs with sensing; None without) ------------------------------------
    @property
    def measurement_names(self) -> list[str] | None:
        """The coordinate each column of `measurements` samples (the sensing groups' order: the C's y layout)."""
        return self.run.measured_names

    @property
    def measurements(self) -> np.ndarray | None:
        """Per instant the measurement y the estimator read (taken delay_periods earlier, noise and quantisation
        included): what `Crane.stateful_controller(...).step(y, t)` or the exported C controller's step is fed
        to replay this run (docs/controller.md, "Replay a run")."""
        return self.run.measurements

    @property
    def estimate(self) -> np.ndarray | None:
        """Per instant the estimate q̂ the controller used (columns: `coordinates`)."""
        return self.run.estimate_q

    @property
    def estimate_rates(self) -> np.ndarray | None:
        """Per instant the estimate q̇̂ the controller used."""
        return self.run.estimate_qd

    @property
    def step_codes(self) -> np.ndarray | None:
        """Per instant the stateful step's code (acroboter.sim.stateful_controller.STEP_CODES: 0 the sample accepted, 4
        rejected and the prediction used; a run stops at any other)."""
        return self.run.step_code

    def input(self, name: str) -> np.ndarray:
        """One input by actuator name, e.g. result.input("tension_1") (N, or N·m for torques)."""
        return self.run.u[:, _index(self.inputs, name, "input")]

    def coordinate(self, name: str) -> np.ndarray:
        """One natural coordinate by name, e.g. result.coordinate("SU.r_z")."""
        return self.run.q[:, _index(self.coordinates, name, "coordinate")]

    def velocity(self, name: str) -> np.ndarray:
        return self.run.qd[:, _index(self.coordinates, name, "coordinate")]

    def tension(self, cable: str) -> np.ndarray:
        """The plant's tension of one cable by name, N."""
        return self.run.cable_tension[:, _index(self.cables, cable, "cable")]

    def cable_gap(self, cable: str) -> np.ndarray:
        """|p_a − p_b| − L of one cable by name at every instant, m: > 0 stretched, < 0 slack by that
        much (a slack cable's ends are closer than its length)."""
        return self.run.cable_gap[:, _index(self.cables, cable, "cable")]

    @property
    def energy_residual(self) -> np.ndarray | None:
        """The plant's energy balance residual at every instant, J: T + U − (T + U)₀ − (W_u + W_anchor −
        E_d + impact energy); None with the MuJoCo plant (its soft limits dissipate energy of their own)."""
        return self.run.energy_residual

    # --- figures ----------------------------------------------------------------------------------
    def summary(self) -> dict:
        """The per-method figures of summary.json: errors, tensions, step times, limits, saturation."""
        if self._summary is None:
            self._summary = summarize(self.run, self.scenario, self.layout)
            if self.run.diverged_at is not None:
                self._summary["diverged_at_s"] = self.run.diverged_at
        return self._summary

    def columns(self, state: bool = False) -> dict[str, np.ndarray]:
        """Named columns with their units in the name (the CSV's header): the tracking figures, inputs,
        cables, the moving anchors and the pose q; state=True adds q̇."""
        cols: dict[str, np.ndarray] = {"t_s": self.time}
        for axis, i in zip("xyz", range(3), strict=True):
            cols[f"{axis}_m"] = self.position[:, i]
        cols["yaw_deg"] = self.yaw_deg
        for axis, i in zip("xyz", range(3), strict=True):
            cols[f"{axis}_d_m"] = self.desired_position[:, i]
        cols["yaw_d_deg"] = self.desired_yaw_deg
        cols["position_error_mm"] = self.position_error_mm
        if self.yaw_error_deg is not None:
            cols["yaw_error_deg"] = self.yaw_error_deg
        cols["tilt_deg"] = self.tilt_deg
        position_rows = range(self.scenario.position_rows.start, self.scenario.position_rows.stop)
        for i, name in enumerate(self.servo_constraints):  # positions in mm, the others unitless
            scale, unit = (1e3, "_mm") if i in position_rows else (1.0, "")
            cols[f"servo_{_slug(name)}{unit}"] = scale * self.run.sigma[:, i]
        for i, (name, unit) in enumerate(zip(self.inputs, self.input_units, strict=True)):
            cols[f"{name}_{_unit_suffix(unit)}"] = self.run.u[:, i]
        for c, cable in enumerate(self.cables):
            cols[f"cable_{cable}_tension_N"] = self.run.cable_tension[:, c]
            cols[f"cable_{cable}_slack"] = (self.run.cable_active[:, c] == 0).astype(np.int8)
            cols[f"cable_{cable}_gap_m"] = self.run.cable_gap[:, c]
        if self.run.energy_residual is not None:
            cols["energy_residual_J"] = self.run.energy_residual
        cols["saturated"] = self.run.saturated.astype(np.int8)
        # The pose (q) and the moving anchors always: enough to draw the crane at every instant.
        for name, j in self.layout.anchor_signal.items():
            for c, axis in enumerate("xyz"):
                cols[f"anchor_{name}_{axis}_m"] = self.run.anchors[:, j + c]
        for i, name in enumerate(self.coordinates):
            unit = "_m" if ".r_" in name or name.endswith(".length") else ""
            cols[f"q_{name}{unit}"] = self.run.q[:, i]
        if self.run.measurements is not None:  # what the controller saw: its code and each measurement
            cols["step_code"] = self.run.step_code.astype(np.int8)
            for j, name in enumerate(self.run.measured_names):
                unit = "_m" if ".r_" in name or name.endswith(".length") else ""
                cols[f"y_{name}{unit}"] = self.run.measurements[:, j]
        if state:
            for i, name in enumerate(self.coordinates):
                unit = "_m_per_s" if ".r_" in name or name.endswith(".length") else "_per_s"
                cols[f"qd_{name}{unit}"] = self.run.qd[:, i]
        return cols

    def to_csv(self, path: str | Path, state: bool = False) -> Path:
        """Write columns(state) as CSV (flags as 0 / 1, numbers with full precision)."""
        cols = self.columns(state)
        path = Path(path)
        integer = {name for name, v in cols.items() if v.dtype.kind in "iub"}
        with path.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(cols)
            for row in zip(*(v.tolist() for v in cols.values()), strict=True):
                writer.writerow(row if not integer else
                                [int(v) if n in integer else v for n, v in zip(cols, row, strict=True)])
        return path

    def to_dataframe(self, state: bool = False):
        """columns(state) as a pandas DataFrame indexed by time (pandas is optional: pip install pandas)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("Result.to_dataframe needs pandas: pip install pandas (or use .columns())") from None
        cols = self.columns(state)
        return pd.DataFrame(cols).set_index("t_s")

    def plot(self, path: str | Path | None = None):
        """Position error, yaw error, tilt and the inputs against time; saved to `path` if given.
        Returns the matplotlib Figure."""
        if path is not None:  # a file: no pyplot, so the caller's backend and figures are left alone
            from matplotlib.figure import Figure

            fig = Figure(figsize=(9, 1.9 * (4 if self.yaw_error_deg is not None else 3) + 0.6))
        else:
            import matplotlib.pyplot as plt

            fig = plt.figure(figsize=(9, 1.9 * (4 if self.yaw_error_deg is not None else 3) + 0.6))
        panels = [("position error [mm]", self.position_error_mm)]
        if self.yaw_error_deg is not None:
            panels.append(("yaw error [deg]", self.yaw_error_deg))
        panels.append(("tilt [deg]", self.tilt_deg))
        rows = len(panels) + 1
        axes = fig.subplots(rows, 1, sharex=True)
        for ax, (label, values) in zip(axes, panels, strict=False):
            ax.plot(self.time, values, lw=0.9)
            ax.set_ylabel(label, fontsize=8)
            ax.grid(alpha=0.3)
        ax = axes[-1]
        for i, (name, unit) in enumerate(zip(self.inputs, self.input_units, strict=True)):
            ax.step(self.time, self.run.u[:, i], where="post", lw=0.8, label=f"{name} [{unit}]")
        ax.set_ylabel("inputs", fontsize=8)
        ax.set_xlabel("t [s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
        fig.suptitle(f"{self.spec_name}: {self.method}")
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=110)
        return fig

    def __repr__(self) -> str:
        s = self.summary()
        err = s["max_position_error_mm"]
        shown = f"{err:.4g} mm" if err is not None and math.isfinite(err) else "unbounded"
        end = f", diverged at {self.diverged_at:.2f} s" if self.diverged_at is not None else ""
        return (f"<Result {self.spec_name} {self.method}: {self.time[-1]:g} s, max position error {shown}"
                f"{', saturated' if s['saturated'] else ''}{end}>")


def _index(names: list[str], name: str, what: str) -> int:
    try:
        return names.index(name)
    except ValueError:
        raise KeyError(f"no {what} named '{name}': the {what}s are {', '.join(names)}") from None
