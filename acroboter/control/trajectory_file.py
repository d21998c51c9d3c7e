"""A sampled trajectory as a CSV file: what `acroboter plan` writes and `acroboter run --trajectory FILE` reads.

One header row of named columns with their units, then one row per sample (comma-separated, `#` starts a
comment line):

    t_s, x_m, y_m, z_m, vx_m_s, vy_m_s, vz_m_s, ax_m_s2, ay_m_s2, az_m_s2[, yaw_rad, yaw_rate_rad_s, yaw_acc_rad_s2]

t from 0, strictly increasing; the tracked point's position (world frame, absolute, m), velocity and
acceleration; optionally the yaw (rad) with its rate and acceleration (all three or none). Other columns
are ignored (a note says which). Between samples the motion is the quintic Hermite interpolant
(acroboter.control.path.SampledTrajectory).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from .path import SampledTrajectory, TrajectoryError

POINT = ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "ax_m_s2", "ay_m_s2", "az_m_s2")
YAW = ("yaw_rad", "yaw_rate_rad_s", "yaw_acc_rad_s2")
COLUMNS = ("t_s", *POINT, *YAW)


def write_trajectory_csv(path: str | Path, trajectory: SampledTrajectory) -> Path:
    """Write `trajectory` in the format above (the yaw columns when it has a yaw), full precision."""
    path = Path(path)
    yaw = trajectory.position.shape[1] == 4
    header = ["t_s", *POINT] + (list(YAW) if yaw else [])
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        for k, t in enumerate(trajectory.times.tolist()):
            row = [t, *trajectory.position[k, :3], *trajectory.velocity[k, :3], *trajectory.acceleration[k, :3]]
            if yaw:
                row += [trajectory.position[k, 3], trajectory.velocity[k, 3], trajectory.acceleration[k, 3]]
            writer.writerow([repr(float(v)) for v in row])
    return path


def read_trajectory_csv(path: str | Path) -> SampledTrajectory:
    """The SampledTrajectory of a CSV file in the format above; TrajectoryError naming the file, the line and
    the column for anything else (a missing column, a word where a number goes, times that do not increase)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise TrajectoryError(f"trajectory file {path}: cannot read it ({getattr(err, 'strerror', None) or err})") \
            from None
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip() and
             not line.lstrip().startswith("#")]
    if not lines:
        raise TrajectoryError(f"trajectory file {path}: empty; expected a header row ({', '.join(COLUMNS[:4])}, ...) "
                              "and one row per sample")
    header_line, header = lines[0][0], [c.strip() for c in next(csv.reader([lines[0][1]]))]
    missing = [c for c in ("t_s", *POINT) if c not in header]
    if missing:
        raise TrajectoryError(f"trajectory file {path}, line {header_line}: no column {', '.join(missing)}; expected "
                              f"{', '.join(COLUMNS[:10])} and optionally {', '.join(YAW)}")
    yaw = [c for c in YAW if c in header]
    if yaw and len(yaw) != 3:
        raise TrajectoryError(f"trajectory file {path}, line {header_line}: the yaw needs all of {', '.join(YAW)}, "
                              f"found only {', '.join(yaw)}")
    wanted = ["t_s", *POINT, *yaw]
    index = [header.index(c) for c in wanted]
    rows = []
    for n, line in lines[1:]:
        cells = next(csv.reader([line]))
        if len(cells) != len(header):
            raise TrajectoryError(f"trajectory file {path}, line {n}: {len(cells)} values for {len(header)} columns")
        row = []
        for name, i in zip(wanted, index, strict=True):
            try:
                value = float(cells[i])
            except ValueError:
                raise TrajectoryError(f"trajectory file {path}, line {n}, column {name}: expected a number, found "
                                      f"{cells[i].strip()!r}") from None
            if not math.isfinite(value):
                raise TrajectoryError(f"trajectory file {path}, line {n}, column {name}: expected a finite number, "
                                      f"found {cells[i].strip()}")
            row.append(value)
        rows.append(row)
    if len(rows) < 2:
        raise TrajectoryError(f"trajectory file {path}: {len(rows)} sample(s); expected at least two")
    data = np.array(rows)
    t = data[:, 0]
    if t[0] != 0.0 or not (np.diff(t) > 0).all():
        bad = 0 if t[0] != 0.0 else int(np.argmin(np.diff(t) > 0)) + 1
        raise TrajectoryError(f"trajectory file {path}, line {lines[1 + bad][0]}: t_s = {t[bad]:g}; the times must "
                              "start at 0 and increase strictly")

    def block(first: int) -> np.ndarray:
        cols = data[:, first : first + 3]
        if yaw:
            cols = np.hstack([cols, data[:, 10 + (first - 1) // 3][:, None]])
        return cols

    return SampledTrajectory(t, block(1), block(4), block(7))
