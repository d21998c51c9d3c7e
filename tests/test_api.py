"""The library's face (acroboter.Crane, Result, trajectories): the example of docs/library.md runs, gives
what the CLI gives for the same options, and names, units and user paths mean what they say."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import acroboter
from acroboter.control.path import TrajectoryError

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def crane():
    return acroboter.Crane.from_example("acroboter")


def library_snippet() -> str:
    """The first python block of docs/library.md (every block of the docs runs in test_docs_examples)."""
    text = (REPO / "docs" / "library.md").read_text()
    return re.search(r"```python\n(.*?)```", text, re.S).group(1)


def test_the_library_example_runs_and_matches_the_cli(tmp_path):
    namespace: dict = {}
    exec(compile(library_snippet(), "docs/library.md", "exec"), namespace)  # noqa: S102 - the docs' own code
    api = namespace["summary"]
    proc = subprocess.run([sys.executable, "-m", "acroboter", "run", "--method", "penalty", "--duration", "5",
                           "--out", str(tmp_path), "--no-plots", "--quiet"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr
    cli = json.loads((tmp_path / "summary.json").read_text())["methods"]["penalty"]
    # Everything but the wall-clock figures is the same physics: equal to the last bit.
    timing = {"control_step_us", "sim_wall_s"}
    assert {k: v for k, v in api.items() if k not in timing} == {k: v for k, v in cli.items() if k not in timing}
    assert api["max_position_error_mm"] < 0.05  # measured 0.0284 mm (2026-12-02); 1.8x (was 0.1)
    # The CSV is Result.to_csv: same header, same numbers.
    with (tmp_path / "penalty.csv").open() as f:
        rows = list(csv.reader(f))
    columns = namespace["columns"]
    assert rows[0] == list(columns)
    assert float(rows[-1][rows[0].index("tension_1_N")]) == namespace["result"].input("tension_1")[-1]
    u = namespace["u"]
    assert u.shape == (6,) and np.allclose(u, namespace["start"].inputs, atol=1e-9)  # at rest: the statics


def test_public_names_are_exported():
    assert acroboter.__version__ and acroboter.__version__ != "0+unknown"
    for name in acroboter.__all__:
        assert getattr(acroboter, name) is not None
    assert "acroboter" in acroboter.example_names() and acroboter.example_spec("lab_crane").is_file()
    with pytest.raises(FileNotFoundError, match="acroboter_4cable"):
        acroboter.example_spec("no_such_crane")


def test_names_address_the_columns(crane):
    result = crane.simulate("mlm", duration=1.0, warm_up=0)
    assert np.array_equal(result.input("tension_2"), result.u[:, crane.inputs.index("tension_2")])
    assert np.array_equal(result.coordinate("SU.r_z"), result.q[:, crane.coordinates.index("SU.r_z")])
    assert np.array_equal(result.tension("L1"), result.cable_tension[:, crane.cables.index("L1")])
    with pytest.raises(KeyError, match="no input named 'tension_9'.*tension_1"):
        result.input("tension_9")
    cols = result.columns(state=True)
    assert "yaw_torque_Nm" in cols and "cable_L1_tension_N" in cols and "q_SU.r_z_m" in cols
    assert "qd_SU.u_x_per_s" in cols and len([c for c in cols if c.startswith("q_")]) == len(crane.coordinates)
    # desired minus realized is the tracking error the summary reports
    err = 1e3 * np.linalg.norm(result.position - result.desired_position, axis=1)
    assert np.allclose(err, result.position_error_mm, rtol=1e-12, atol=1e-12)
    assert result.summary()["max_position_error_mm"] == pytest.approx(err.max(), rel=1e-9)


def test_csv_round_trip(crane, tmp_path):
    result = crane.simulate("penalty", duration=0.5, warm_up=0)
    path = result.to_csv(tmp_path / "r.csv", state=True)
    with path.open() as f:
        rows = list(csv.reader(f))
    header = rows[0]
    assert header[:3] == ["t_s", "x_m", "y_m"] and "saturated" in header
    data = np.array([[float(v) for v in row] for row in rows[1:]])
    assert np.array_equal(data[:, header.index("q_SU.r_x_m")], result.coordinate("SU.r_x"))
    assert set(data[:, header.index("cable_main_slack")]) <= {0.0, 1.0}


def test_to_dataframe_names_pandas_when_missing(crane, monkeypatch):
    result = crane.simulate("penalty", duration=0.2, warm_up=0)
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match="pip install pandas"):
        result.to_dataframe()


def test_settings_are_checked(crane):
    with pytest.raises(TypeError, match="unknown controller setting.*kpp"):
        crane.simulate("penalty", duration=0.1, kpp=3.0)
    with pytest.raises(ValueError, match=r"kd: expected 0 < kd <= 1e4 \(1/s\), found nan"):
        crane.controller("penalty", kd=float("nan"))
    with pytest.raises(ValueError, match="kappa: expected 0 <= kappa <= 1, found 2"):
        crane.gains(kappa=2.0)
    with pytest.raises(ValueError, match="unknown method 'newton'"):
        crane.controller("newton")
    with pytest.raises(ValueError, match="iterations: expected a whole number"):
        crane.controller("iterative", iterations=0)
    assert crane.method_name("iterative") == "iterative-3"  # the spec's first count


def _spec_path_samples(path, count: int = 40):
    """Samples of the spec's path at every edge boundary and between, with its exact derivatives."""
    times = np.unique(np.concatenate([path.edge_t0, [path.duration], np.linspace(0, path.duration, count)]))
    table = path.table(times)
    ns, p = path.n_signals, path.layout.path_signal
    pick = [slice(p, p + 4), slice(ns + p, ns + p + 4), slice(2 * ns + p, 2 * ns + p + 4)]
    return times, [table[:, s] for s in pick]


def test_a_sampled_trajectory_of_the_spec_path_is_the_spec_path(crane):
    """The path is quintic between edge boundaries and the yaw one quintic: the quintic Hermite
    interpolant through samples that include the boundaries reproduces it to round-off."""
    path = crane.path
    times, (pos, vel, acc) = _spec_path_samples(path)
    trajectory = acroboter.SampledTrajectory(times, pos, vel, acc)
    user = crane.desired(trajectory)
    check = np.linspace(0.0, path.duration, 777)
    assert user.duration == pytest.approx(path.duration)
    assert np.abs(user.table(check) - path.table(check)).max() < 1e-9
    ours = crane.simulate("penalty", duration=8.0, trajectory=trajectory, warm_up=0).summary()
    spec = crane.simulate("penalty", duration=8.0, warm_up=0).summary()
    assert ours["max_position_error_mm"] == pytest.approx(spec["max_position_error_mm"], rel=1e-6)


def test_a_trajectory_function_is_followed(crane):
    """A horizontal circle of radius 5 cm around the start point, started and ended at rest by a
    quintic angle profile: the desired positions are the function's, and the crane tracks it."""
    start = crane.path.start_point
    radius, T = 0.05, 8.0

    def circle(t):
        tau = np.clip(t / T, 0, 1)
        s = 2 * np.pi * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        ds = 2 * np.pi * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
        dds = 2 * np.pi * (60 * tau - 180 * tau**2 + 120 * tau**3) / T**2
        pos = start + radius * np.stack([np.cos(s) - 1, np.sin(s), 0 * s], axis=1)
        vel = radius * np.stack([-np.sin(s) * ds, np.cos(s) * ds, 0 * s], axis=1)
        acc = radius * np.stack([-np.cos(s) * ds**2 - np.sin(s) * dds, -np.sin(s) * ds**2 + np.cos(s) * dds,
                                 0 * s], axis=1)
        return pos, vel, acc

    result = crane.simulate("mlm", trajectory=circle, duration=T, warm_up=0)
    expected, _, _ = circle(result.time)
    assert np.abs(result.desired_position - expected).max() < 1e-12
    assert result.summary()["max_position_error_mm"] < 0.2  # measured 0.104 mm (2026-12-02); 1.9x (was 1.0)
    assert result.time[-1] == pytest.approx(T)


def test_bad_trajectories_are_refused_with_the_cause(crane):
    t = np.linspace(0, 1, 5)
    ok = np.zeros((5, 3))
    with pytest.raises(TrajectoryError, match="start at 0 and increase"):
        acroboter.SampledTrajectory(t[::-1], ok, ok, ok)
    with pytest.raises(TrajectoryError, match="5 x 3 or 5 x 4"):
        acroboter.SampledTrajectory(t, ok, np.zeros((5, 2)), ok)
    with pytest.raises(TrajectoryError, match="finite"):
        acroboter.SampledTrajectory(t, ok + np.nan, ok, ok)
    with pytest.raises(ValueError, match="needs its duration"):
        crane.simulate("penalty", trajectory=lambda t: (ok, ok, ok))
    with pytest.raises(TrajectoryError, match="position for 1 times"):
        crane.simulate("penalty", trajectory=lambda t: (ok, ok, ok), duration=1.0)


def test_the_controller_alone_holds_the_static_load(crane):
    """At the static equilibrium at rest every method asks exactly the static inputs (statics oracle:
    the equilibrium solve, independent of the controllers)."""
    start = crane.equilibrium()
    rest = np.zeros(len(crane.coordinates))
    for method in ("mlm", "penalty", "iterative-4"):
        controller = crane.controller(method)
        u = controller.step(start.q, rest, 0.0)
        assert np.allclose(u, start.inputs, atol=1e-8), method
        assert not controller.saturated() and not controller.limit_state.any()
