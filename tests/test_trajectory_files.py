"""Issue 36: a trajectory file the user gives is checked before any work: bounded in size and rows (never read
until the kernel kills the process), every value finite and within the spec's ranges, times increasing, and no
jump between two rows; each problem names the line and the column. Malformed files are generated (hypothesis)
from a good one, one defect each, and each must be refused naming the line where the defect is."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acroboter.control.path import SampledTrajectory, TrajectoryError
from acroboter.control.trajectory_file import MAX_BYTES, MAX_ROWS, read_trajectory_csv, write_trajectory_csv


def good_trajectory(samples: int = 40, yaw: bool = True) -> SampledTrajectory:
    """A smooth rest-to-rest move of 0.4 m and a quarter turn in 2 s (minimum jerk), sampled."""
    t = np.linspace(0.0, 2.0, samples)
    s = t / 2.0
    shape, rate, acc = 10 * s**3 - 15 * s**4 + 6 * s**5, (30 * s**2 - 60 * s**3 + 30 * s**4) / 2.0, \
        (60 * s - 180 * s**2 + 120 * s**3) / 4.0
    direction = np.array([0.3, -0.2, 0.1, math.pi / 2])[: 4 if yaw else 3]
    start = np.array([0.1, 0.2, 0.9, 0.0])[: 4 if yaw else 3]
    return SampledTrajectory(t, start + np.outer(shape, direction), np.outer(rate, direction),
                             np.outer(acc, direction))


def written(tmp_path: Path, name: str = "good.csv", **kwargs) -> Path:
    return write_trajectory_csv(tmp_path / name, good_trajectory(**kwargs))


def test_a_good_file_reads_back_as_written(tmp_path):
    back = read_trajectory_csv(written(tmp_path))
    original = good_trajectory()
    assert np.array_equal(back.times, original.times) and np.array_equal(back.position, original.position)


def test_a_plans_trajectory_is_continuous_at_its_own_sampling(tmp_path):
    """The continuity check leaves a coarsely sampled smooth motion alone (8 samples over a 2 s move)."""
    read_trajectory_csv(written(tmp_path, samples=8))


DEFECTS = ("nan", "inf", "word", "huge", "yaw", "time_back", "jump")


def with_defect(lines: list[str], row: int, defect: str) -> list[str]:
    """`lines` (header first) with one defect in data row `row` (0-based)."""
    out = list(lines)
    cells = out[row + 1].split(",")
    if defect in ("nan", "inf", "word"):
        cells[2] = {"nan": "nan", "inf": "-inf", "word": "ten"}[defect]
    elif defect == "huge":
        cells[4] = "1e6"  # vx: 1000 km/s
    elif defect == "yaw":
        cells[10] = "1e19"
    elif defect == "time_back":
        cells[0] = repr(float(out[row].split(",")[0]) if row else 1.0)  # the time before it again (or t0 != 0)
    elif defect == "jump":
        cells[1] = repr(float(cells[1]) + 50.0)
    out[row + 1] = ",".join(cells)
    return out


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(0, 39), defect=st.sampled_from(DEFECTS))
def test_each_defect_is_refused_naming_its_line(tmp_path, row, defect):
    lines = written(tmp_path).read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(with_defect(lines, row, defect)) + "\n")
    with pytest.raises(TrajectoryError) as caught:
        read_trajectory_csv(bad)
    message = str(caught.value)
    # the data row `row` is line row + 2 (the header is line 1); a time that goes back at row 0 is t0 != 0, and a
    # jump may be seen at the row after it (the path jumps back)
    lines_named = {f"line {row + 2}"} | ({f"line {row + 3}"} if defect == "jump" else set())
    assert any(name in message for name in lines_named), message
    if defect in ("nan", "inf", "word", "huge", "yaw"):
        column = {"nan": "y_m", "inf": "y_m", "word": "y_m", "huge": "vx_m_s", "yaw": "yaw_rad"}[defect]
        assert f"column {column}" in message, message


def test_a_device_or_an_oversized_file_is_refused_before_it_is_read(tmp_path):
    with pytest.raises(TrajectoryError, match="not a regular file"):
        read_trajectory_csv("/dev/zero")  # read until the kernel killed the process (23.9 GB in 15 s)
    big = tmp_path / "big.csv"
    with big.open("wb") as f:  # sparse: no disk, no time
        f.truncate(MAX_BYTES + 1)
    with pytest.raises(TrajectoryError, match=f"more than {MAX_BYTES // 2**20} MB"):
        read_trajectory_csv(big)
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    with pytest.raises(TrajectoryError, match="not a regular file"):
        read_trajectory_csv(fifo)


def test_too_many_rows_are_refused_with_the_bound(tmp_path):
    rows = tmp_path / "rows.csv"
    header = "t_s,x_m,y_m,z_m,vx_m_s,vy_m_s,vz_m_s,ax_m_s2,ay_m_s2,az_m_s2\n"
    rows.write_text(header + "".join(f"{k},0,0,1,0,0,0,0,0,0\n" for k in range(MAX_ROWS + 1)))
    with pytest.raises(TrajectoryError, match=f"{MAX_ROWS + 1} samples, more than {MAX_ROWS:,}"):
        read_trajectory_csv(rows)


def test_run_refuses_a_bad_trajectory_with_exit_2_and_writes_nothing(tmp_path, capsys):
    from acroboter.cli.run import main

    lines = written(tmp_path).read_text().splitlines()
    bad = tmp_path / "jump.csv"
    bad.write_text("\n".join(with_defect(lines, 20, "jump")) + "\n")
    for trajectory, named in ((bad, "line 22: the path jumps 50"), (Path("/dev/zero"), "not a regular file")):
        assert main(["--trajectory", str(trajectory), "--out", str(tmp_path / "out"), "-q"]) == 2
        err = capsys.readouterr().err
        assert named in err, err
        assert not (tmp_path / "out").exists()
