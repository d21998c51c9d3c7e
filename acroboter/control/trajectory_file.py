"""A sampled trajectory as a CSV file: what `acroboter plan` writes and `acroboter run --trajectory FILE` reads.

One header row of named columns with their units, then one row per sample (comma-separated, `#` starts a
comment line):

    t_s, x_m, y_m, z_m, vx_m_s, vy_m_s, vz_m_s, ax_m_s2, ay_m_s2, az_m_s2[, yaw_rad, yaw_rate_rad_s, yaw_acc_rad_s2]

t from 0, strictly increasing; the tracked point's position (world frame, absolute, m), velocity and
acceleration; optionally the yaw (rad) with its rate and acceleration (all three or none). Other columns
are ignored (a note says which). Between samples the motion is the quintic Hermite interpolant
(acroboter.control.path.SampledTrajectory).

A file is checked before any work, each problem naming the file, the line and the column: a regular file of at
most MAX_BYTES and MAX_ROWS samples (`/dev/zero` or a million rows is refused before it is read); every value
finite and within the spec's ranges (positions the coordinates' ±1e4 m, the yaw ±3600°, times up to 1e6 s, speeds
up to 100 m/s as a path's mean speed, accelerations up to 1000 m/s² as a plan's bound); and continuous: between two
rows the point moves no further than its velocities and accelerations there allow (JUMP_FACTOR times that, plus
JUMP_SLACK_M), else the row where the path jumps is named.
"""

from __future__ import annotations

import csv
import math
import os
import stat
from pathlib import Path

import numpy as np

from ..model.ranges import COORDINATE, DURATION, MEAN_SPEED, PATH_YAW, PLAN_ACCEL
from .path import SampledTrajectory, TrajectoryError

POINT = ("x_m", "y_m", "z_m", "vx_m_s", "vy_m_s", "vz_m_s", "ax_m_s2", "ay_m_s2", "az_m_s2")
# Bounds of a file (checked before it is read): 100,000 samples of 13 full-precision numbers are about 33 MB.
MAX_BYTES = 64 * 2**20
MAX_ROWS = 100_000
# The ranges of the values, (low, high, unit, why) per column kind: the spec's and the options' own
# (acroboter.model.ranges), the yaw in radians.
_YAW_TURN = math.radians(PATH_YAW.high)
_KINDS = {"time": (0.0, DURATION.high, "s", "the longest run"),
          "position": (COORDINATE.low, COORDINATE.high, "m", "the coordinates' window"),
          "velocity": (-MEAN_SPEED.high, MEAN_SPEED.high, "m/s", "a path's largest mean speed"),
          "acceleration": (-PLAN_ACCEL.high, PLAN_ACCEL.high, "m/s²", "a plan's largest --max-accel"),
          "yaw": (-_YAW_TURN, _YAW_TURN, "rad", "the spec's yaw_deg: ten turns"),
          "yaw rate": (-1e3, 1e3, "rad/s", "a turn in 6 ms"), "yaw acceleration": (-1e5, 1e5, "rad/s²", "")}
LIMITS = {"t_s": _KINDS["time"], "yaw_rad": _KINDS["yaw"], "yaw_rate_rad_s": _KINDS["yaw rate"],
          "yaw_acc_rad_s2": _KINDS["yaw acceleration"],
          **{name: _KINDS["position"] for name in POINT[0:3]}, **{name: _KINDS["velocity"] for name in POINT[3:6]},
          **{name: _KINDS["acceleration"] for name in POINT[6:9]}}
# Continuity: a row further from the last than JUMP_FACTOR × (Δt·|v| + Δt²·|a|) + JUMP_SLACK_M is a jump.
JUMP_FACTOR = 4.0
JUMP_SLACK_M = 1e-3
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
    the column for anything else (a missing column, a word where a number goes, times that do not increase, a value
    outside its range, a jump)."""
    path = Path(path)
    text = _bounded_text(path)
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1) if line.strip() and
             not line.lstrip().startswith("#")]
    if not lines:
        raise TrajectoryError(f"trajectory file {path}: empty; expected a header row ({', '.join(COLUMNS[:4])}, ...) "
                              "and one row per sample")
    if len(lines) - 1 > MAX_ROWS:
        raise TrajectoryError(f"trajectory file {path}: {len(lines) - 1} samples, more than {MAX_ROWS:,}: sample "
                              "the trajectory more coarsely (between samples it is interpolated, quintic Hermite)")
    header_line, header = lines[0][0], [c.strip() for c in _cells(path, lines[0])]
    if len(set(header)) != len(header):
        twice = sorted({c for c in header if header.count(c) > 1})
        raise TrajectoryError(f"trajectory file {path}, line {header_line}: column {', '.join(twice)} named twice; "
                              "give each column once")
    missing = [c for c in ("t_s", *POINT) if c not in header]
    if missing:
        raise TrajectoryError(f"trajectory file {path}, line {header_line}: no column {', '.join(missing)}; expected "
                              f"{', '.join(COLUMNS[:10])} and optionally {', '.join(YAW)}")
    yaw = [c for c in YAW if c in header]
    if yaw and len(yaw) != 3:
        raise TrajectoryError(f"trajectory file {path}, line {header_line}: the yaw needs all of {', '.join(YAW)}, "
                              f"found only {', '.join(yaw)}")
    wanted = ["t_s", *POINT, *yaw]
    data = _values(path, lines[1:], header, wanted)
    t = data[:, 0]
    if t[0] != 0.0 or not (np.diff(t) > 0).all():
        bad = 0 if t[0] != 0.0 else int(np.argmin(np.diff(t) > 0)) + 1
        raise TrajectoryError(f"trajectory file {path}, line {lines[1 + bad][0]}: t_s = {t[bad]:g}; the times must "
                              "start at 0 and increase strictly")
    _check_continuity(path, [n for n, _ in lines[1:]], data)

    def block(first: int) -> np.ndarray:
        cols = data[:, first : first + 3]
        if yaw:
            cols = np.hstack([cols, data[:, 10 + (first - 1) // 3][:, None]])
        return cols

    return SampledTrajectory(t, block(1), block(4), block(7))


def _bounded_text(path: Path) -> str:
    """The file's text, read only when it is a regular file of at most MAX_BYTES."""
    try:
        # O_NONBLOCK: opening a pipe with no writer must not wait for one (it is refused below, as a device is)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        with os.fdopen(fd, "rb") as f:
            info = os.fstat(f.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise TrajectoryError(f"trajectory file {path}: not a regular file (a device, a pipe or a folder); "
                                      "give a CSV file")
            if info.st_size > MAX_BYTES:
                raise TrajectoryError(f"trajectory file {path}: {info.st_size / 2**20:.0f} MB, more than "
                                      f"{MAX_BYTES // 2**20} MB ({MAX_ROWS:,} samples need about half of it): sample "
                                      "the trajectory more coarsely")
            raw = f.read(MAX_BYTES + 1)
        return raw.decode("utf-8-sig")  # -sig: the byte-order mark spreadsheets write ("CSV UTF-8") goes
    except (OSError, UnicodeDecodeError) as err:
        raise TrajectoryError(f"trajectory file {path}: cannot read it ({getattr(err, 'strerror', None) or err})") \
            from None


def _cells(path: Path, numbered: tuple[int, str]) -> list[str]:
    """One CSV line's cells; TrajectoryError naming the line for what the csv module refuses (a field of more than
    131,072 characters, an unclosed quote)."""
    n, line = numbered
    try:
        return next(csv.reader([line]))
    except csv.Error as err:
        raise TrajectoryError(f"trajectory file {path}, line {n}: not a CSV row ({err})") from None


def _values(path: Path, rows: list[tuple[int, str]], header: list[str], wanted: list[str]) -> np.ndarray:
    """The wanted columns of every row as numbers, each finite and within its range."""
    index = [header.index(c) for c in wanted]
    limits = [LIMITS[name] for name in wanted]
    data = np.empty((len(rows), len(wanted)))
    for r, (n, line) in enumerate(rows):
        cells = _cells(path, (n, line))
        if len(cells) != len(header):
            raise TrajectoryError(f"trajectory file {path}, line {n}: {len(cells)} values for {len(header)} columns")
        for c, (name, i) in enumerate(zip(wanted, index, strict=True)):
            try:
                value = float(cells[i])
            except ValueError:
                raise TrajectoryError(f"trajectory file {path}, line {n}, column {name}: expected a number, found "
                                      f"{cells[i].strip()!r}") from None
            low, high, unit, why = limits[c]
            if not math.isfinite(value):
                raise TrajectoryError(f"trajectory file {path}, line {n}, column {name}: expected a finite number, "
                                      f"found {cells[i].strip()}")
            if not low <= value <= high:
                raise TrajectoryError(f"trajectory file {path}, line {n}, column {name}: expected {low:g} <= {name} "
                                      f"<= {high:g} ({unit}{': ' + why if why else ''}), found {value:g}")
            data[r, c] = value
    if len(rows) < 2:
        raise TrajectoryError(f"trajectory file {path}: {len(rows)} sample(s); expected at least two")
    return data


def _check_continuity(path: Path, line_numbers: list[int], data: np.ndarray) -> None:
    """A row further from the one before than its velocities and accelerations allow is a jump: named."""
    dt = np.diff(data[:, 0])
    step = np.linalg.norm(np.diff(data[:, 1:4], axis=0), axis=1)
    speed = np.linalg.norm(data[:, 4:7], axis=1)
    accel = np.linalg.norm(data[:, 7:10], axis=1)
    reach = dt * np.maximum(speed[:-1], speed[1:]) + dt**2 * np.maximum(accel[:-1], accel[1:])
    jumps = np.flatnonzero(step > JUMP_FACTOR * reach + JUMP_SLACK_M)
    if jumps.size:
        k = int(jumps[0])
        raise TrajectoryError(
            f"trajectory file {path}, line {line_numbers[k + 1]}: the path jumps {step[k]:.4g} m from the row before "
            f"in {dt[k]:.4g} s, where its velocities ({speed[k]:.3g}, {speed[k + 1]:.3g} m/s) and accelerations "
            f"({accel[k]:.3g}, {accel[k + 1]:.3g} m/s²) allow at most {reach[k]:.3g} m; give the samples in between, "
            "or velocities and accelerations that match the positions")
