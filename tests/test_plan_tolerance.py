"""Plans the crane flies within a tolerance (issue 34 items 1-2): smooth timings, `--max-jerk`, `--tolerance`
(acroboter.planning.servo_lag, acroboter.planning.tolerance, docs/planning.md "A tolerance").

Oracles: the servo lag model's closed form (a constant jerk from rest through ë + 2kd ė + kp² e = −(T/2) j), the
flights of the own plant under the spec's controllers (the model is a prediction of them, tested against them on
timings it never saw), the lift's input law (tests/test_planning.py) and the written trajectory's own samples
(its jerk and acceleration by finite differences, not by the planner's formulas).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_lift_spec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_planning import lift_coefficients

import acroboter
from acroboter.control.path import SampledTrajectory
from acroboter.planning.servo_lag import lag_step, lag_substeps, predicted_error

PERIOD = 0.02  # the default crane's controller: 50 Hz, kp = kd = 5 1/s


def closed_form_lag(t: np.ndarray, jerk: float, kp: float, kd: float, period: float) -> np.ndarray:
    """e(t) of ë + 2kd ė + kp² e = c, c = −(T/2)·jerk, from rest: c/kp² (1 + (r2 e^{r1 t} − r1 e^{r2 t})/(r1 − r2)),
    r1, r2 the roots of s² + 2kd s + kp² (complex when underdamped); kd = kp: c/kp² (1 − (1 + kp t) e^{−kp t})."""
    c = -0.5 * period * jerk
    if abs(kd - kp) < 1e-12:
        return c / kp**2 * (1.0 - (1.0 + kp * t) * np.exp(-kp * t))
    root = np.sqrt(complex(kd * kd - kp * kp))
    r1, r2 = -kd + root, -kd - root
    return np.real(c / kp**2 * (1.0 + (r2 * np.exp(r1 * t) - r1 * np.exp(r2 * t)) / (r1 - r2)))


@settings(max_examples=25, deadline=None, derandomize=True)
@given(kp=st.floats(1.0, 20.0), ratio=st.floats(0.3, 3.0), jerk=st.floats(-50.0, 50.0), duration=st.floats(0.05, 2.0))
def test_both_forms_of_the_lag_model_follow_its_closed_form(kp, ratio, jerk, duration):
    """The optimiser's form (CasADi RK4, lag_step) and the library's scipy form (lsim, predicted_error) against the
    closed form: a constant jerk for `duration`, then none (superposition: the step minus the step delayed)."""
    kd = kp * ratio
    h = duration / 4
    substeps = lag_substeps(h, kp, kd)  # the optimiser's rule: RK4 steps of at most LAG_STEP_RATE / fastest pole
    _, errors = lag_step(kp, kd, PERIOD, substeps).mapaccum(4)(np.zeros(6), np.tile([[jerk], [0.0], [0.0]], 4), h)
    t = h / substeps * np.arange(1, 4 * substeps + 1)
    expected = closed_form_lag(t, jerk, kp, kd, PERIOD)
    scale = abs(0.5 * PERIOD * jerk) / kp**2 + 1e-15  # the steady lag
    assert np.allclose(np.asarray(errors)[0], expected, atol=1e-4 * scale)
    grid = np.arange(0.0, duration + 3.0, 1e-4)
    response = closed_form_lag(grid, jerk, kp, kd, PERIOD) - np.where(
        grid > duration, closed_form_lag(np.maximum(grid - duration, 0.0), jerk, kp, kd, PERIOD), 0.0)
    samples = np.linspace(0.0, duration, 200)
    drive = np.column_stack([np.full(200, jerk), np.zeros(200), np.zeros(200)])
    # lsim's input is linear between samples and ends at `duration`: the last millisecond ramps down
    assert predicted_error(samples, drive, kp, kd, PERIOD, settle_s=3.0) == pytest.approx(
        np.abs(response).max(), rel=2e-2, abs=1e-3 * scale)


def quintic_lift(duration: float) -> SampledTrajectory:
    t = np.linspace(0.0, 1.0, 2001)
    s, sd, sdd = 10 * t**3 - 15 * t**4 + 6 * t**5, 30 * t**2 - 60 * t**3 + 30 * t**4, 60 * t - 180 * t**2 + 120 * t**3
    columns = [np.zeros((t.size, 4)) for _ in range(3)]
    for column, values in zip(columns, (s, sd / duration, sdd / duration**2), strict=True):
        column[:, 2] = 0.1 * values
    return SampledTrajectory(t * duration, *columns)


@pytest.fixture(scope="module")
def lift_crane(tmp_path_factory):
    return acroboter.Crane.from_toml(write_lift_spec(tmp_path_factory.mktemp("lift")))


@settings(max_examples=6, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(duration=st.floats(0.9, 4.0))
def test_the_lag_model_predicts_the_flights_of_smooth_lifts(lift_crane, duration):
    """The model behind --tolerance, against the own plant flown by each method on quintic lifts it was not fitted
    to: measured 3-9 % above the flights on 0.9-3 s (2026-12-06; servo_lag's docstring). A model that predicted
    less than the flight (the plan would then miss its tolerance in its first round) or over 20 % more (it would
    plan needlessly slowly) fails here; so would a lag with the wrong sign of kd, or without T/2."""
    trajectory = quintic_lift(duration)
    t = trajectory.times
    jerk = np.zeros((t.size, 3))
    x = t / duration
    jerk[:, 2] = 0.1 * (60 - 360 * x + 360 * x * x) / duration**3
    c = lift_crane.spec.controller
    model = predicted_error(t, jerk, c.kp, c.kd, 1.0 / c.rate_hz)
    for method in ("mlm", "penalty"):
        flown = 1e-3 * lift_crane.simulate(method, trajectory=trajectory).position_error_mm.max()
        assert 0.8 * model <= flown <= model, (method, duration, flown, model)


@settings(max_examples=2, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(max_jerk=st.floats(0.5, 20.0))
def test_a_jerk_bound_holds_on_the_written_samples_and_the_acceleration_never_jumps(lift_crane, max_jerk):
    """--max-jerk: the tracked point's jerk by finite differences of the written accelerations stays within the
    bound, the acceleration is continuous (0 at both ends), and the lift's input law holds the bounds every ms."""
    plan = lift_crane.plan(margin=0.2, intervals=8, certify=False, max_jerk=max_jerk)
    t = np.arange(0.0, plan.duration, 2e-4)
    position, velocity, acceleration = plan.trajectory(t)
    jerk = np.abs(np.diff(acceleration[:, 2])) / 2e-4
    assert jerk.max() <= max_jerk * (1 + 1e-3)
    assert abs(acceleration[0, 2]) < 1e-9 and abs(plan.accelerations[-1, 2]) < 1e-6
    assert plan.summary()["timing"].startswith("smooth") and plan.peak_jerk <= max_jerk * (1 + 1e-9)
    a, b = lift_coefficients(position[:, 2] - position[0, 2], velocity[:, 2])
    u = a * acceleration[:, 2] + b
    assert u.max() <= 28.0 + 1e-3 and u.min() >= 25.0 - 1e-3


def test_a_plan_to_a_tolerance_flies_within_it_at_any_clock_phase_and_beats_the_uniform_slowdown(lift_crane):
    """--tolerance 0.1 mm on the lift (limits [24, 29] N, 20 %, 8 intervals), MLM and penalty. Measured 2026-12-06:
    1.882 s in two rounds (the first, 1.854 s, flew at 0.101 mm), flown within 0.0965 mm at every clock phase; the
    time-optimal timing 0.866 s flies at 1.50 mm, and its best
    uniform slowdown that meets 0.1 mm at every clock phase takes 2.81 s. Flown again here by the library's own
    simulate (not the planner's certificate), started at a third of a period after a sample, a phase the planner
    did not fly: within 0.1 mm, never saturated, and so 1 s after the end, where the lag peaks (0.0975 mm at phase
    0, 0.138 s after the end, where the flight to the end had 0.0963 mm; the certificate flies that second too)."""
    plan = lift_crane.plan(margin=0.2, intervals=8, certify=["mlm", "penalty"], tolerance=1e-4)
    record = plan.tolerance
    assert record["met"] and record["flown_mm"] <= 0.1
    assert record["time_optimal_duration_s"] < plan.duration < record["uniform_slowdown_duration_s"]
    assert record["faster_than_uniform_slowdown"] and record["time_optimal_flown_mm"] > 0.1
    late = 1.0 / 3.0 * PERIOD
    tr = plan.trajectory
    rest = np.zeros((2, 4))
    shifted = SampledTrajectory(np.concatenate([[0.0, late - 1e-6], tr.times + late]),
                                np.vstack([tr.position[:1], tr.position[:1], tr.position]),
                                np.vstack([rest, tr.velocity]), np.vstack([rest, tr.acceleration]))
    for method in ("mlm", "penalty"):  # on to 1 s past the end, the point held: the servo law's lag peaks after it
        result = lift_crane.simulate(method, trajectory=shifted, duration=shifted.duration + 1.0)
        assert result.position_error_mm.max() <= 0.1 and not result.saturated.any()


def test_the_lag_drive_is_the_tracked_points_jerk_where_nothing_swings(lift_crane):
    """The optimiser drives the lag model by E u̇ (the servo-constraint jerk a held input misses, through the ideal
    dynamics' inputs and E = σ_q P H); on the vertical lift, where nothing swings, that is the tracked point's jerk
    0.1 m × σ⃛ (the edge is 0.1 m long), found here from the geometry alone; sideways, nothing. (The model test above
    drives the same model by that jerk and checks it against the plant's flights.)"""
    from acroboter.planning.geometry import PathGeometry
    from acroboter.planning.ideal_motion import IdealDynamics, rk4_step

    q0 = lift_crane.equilibrium().q
    dyn = IdealDynamics(lift_crane.spec, q0)
    step = rk4_step(dyn, PathGeometry(lift_crane.desired()), 20)
    x0 = np.concatenate([q0, np.zeros(dyn.layout.n), [0.0, 0.0]])
    for jerk in (0.5, 2.0):  # forwards from rest (the path is not run backwards: σ < 0 is its start)
        drive = np.asarray(step(x0, 0.0, jerk, 0.2)[5])
        assert np.abs(drive[:2]).max() < 1e-6 * abs(jerk)
        # at rest exactly; as the lift gathers speed E moves a little (measured 2.3 % after 0.2 s at 0.5 m/s³)
        assert abs(drive[2, 0]) == pytest.approx(0.1 * abs(jerk), rel=1e-3)
        assert np.abs(drive[2]) == pytest.approx(0.1 * abs(jerk), rel=5e-2)


@pytest.mark.parametrize("text, metres", [("0.1mm", 1e-4), ("100um", 1e-4), ("100µm", 1e-4), ("1e-4m", 1e-4),
                                          ("0.1", 1e-4), (" 2 mm ", 2e-3)])
def test_the_tolerance_option_reads_a_length_with_its_unit(text, metres):
    from acroboter.cli.plan import parse_args

    assert parse_args(["--tolerance", text]).tolerance == pytest.approx(metres, rel=1e-12)


@pytest.mark.parametrize("argv, message", [
    (["--tolerance", "fast"], "expected a length as 0.1mm"),
    (["--tolerance", "0mm"], "tolerance: expected 1e-7 <= tolerance <= 1"),
    (["--tolerance", "2m"], "tolerance: expected 1e-7 <= tolerance <= 1"),
    (["--tolerance", "nanmm"], "tolerance: expected"),
    (["--tolerance", "0.1mm", "--no-certificate"], "cannot go with --no-certificate"),
    (["--max-jerk", "0"], "--max-jerk: expected 0 < max_jerk"),
])
def test_bad_tolerance_and_jerk_options_exit_2_naming_the_option(argv, message, capsys):
    from acroboter.cli.plan import parse_args

    with pytest.raises(SystemExit) as stop:
        parse_args(argv)
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_bad_tolerance_arguments_are_refused_before_any_work(lift_crane):
    from acroboter.model.ranges import RangeError
    from acroboter.planning.ideal_motion import PlanningError

    with pytest.raises(RangeError, match="tolerance: expected"):
        lift_crane.plan(tolerance=0.0)
    with pytest.raises(RangeError, match="max_jerk: expected"):
        lift_crane.plan(max_jerk=-1.0)
    with pytest.raises(PlanningError, match="judged by flying the plan"):
        lift_crane.plan(tolerance=1e-4, certify=False)


def test_the_gains_a_missed_tolerance_asks_for_are_stable_or_said_not_to_be():
    """A tolerance the rounds cannot meet names the gains that would (the lag goes as 1/kp² at a fixed kd/kp), and
    says when the servo law sampled at the spec's rate would not be stable with them (acroboter.model.ranges)."""
    from types import SimpleNamespace

    from acroboter.model.ranges import sampled_gain_problems
    from acroboter.planning.tolerance import stiffer_gains

    model = SimpleNamespace(spec=SimpleNamespace(controller=SimpleNamespace(kp=5.0, kd=5.0, rate_hz=50.0)))
    text = stiffer_gains(model, 4e-4, 1e-4)  # twice the gains: kp = kd = 10, stable at 50 Hz
    assert "about kp = 10, kd = 10 1/s would" in text and not sampled_gain_problems(10.0, 10.0, 50.0)
    text = stiffer_gains(model, 1e-1, 1e-4)  # kp = kd = 158: kd T > 1, not stable
    assert "not stable" in text and sampled_gain_problems(158.0, 158.0, 50.0)


def test_a_warm_start_is_each_phases_nodes_and_duration_or_nothing_on_another_grid():
    """planner.warm_start: a later round's starting guess from an earlier plan, phase by phase (σ̈ at the phase's
    nodes, both ends included, in the problem's σ units; the phase's duration), and nothing when the grids differ."""
    from types import SimpleNamespace

    from acroboter.planning.planner import warm_start

    times = np.array([0.0, 0.5, 1.0, 2.0, 2.5, 3.0, 3.5])
    sdd = np.array([0.0, 0.4, 0.0, 0.0, -0.2, 0.1, 0.0])  # per unit of the path (σ / end)
    nodes, durations = warm_start(SimpleNamespace(times=times, sdd=sdd), [2, 4], end=2.0)
    assert [list(n) for n in nodes] == [[0.0, 0.8, 0.0], [0.0, 0.0, -0.4, 0.2, 0.0]]
    assert durations == [1.0, 2.5]
    assert warm_start(SimpleNamespace(times=times, sdd=sdd), [3, 4], end=2.0) is None


def test_a_later_round_that_is_not_solved_leaves_the_last_rounds_plan_and_says_so(monkeypatch):
    """A narrower bound can leave an edge without a timing (drawn path 0, 2026-12-07: the whole search was lost, the
    summary said "flown at None mm"). The last round's plan stands: returned in the PlanFailure (the CLI writes it to
    failed/plan/, exit 3), flown beyond the tolerance, its rounds saying which bound was not solved and why."""
    from types import SimpleNamespace

    import acroboter.planning.tolerance as tolerance
    from acroboter.planning.planner import PlanFailure

    rounds = []

    def scripted_plan(model, path, q0, **options):
        rounds.append(options["lag"][0])
        plan = SimpleNamespace(duration=2.0 + len(rounds), solve_s=1.0, failures=[], trajectory=None, bounds=None,
                               certificate=None)
        if len(rounds) == 2:
            plan.failures.append("the time-optimal problem of phase(s) 1 was not solved (Infeasible_Problem_Detected)")
            raise PlanFailure("; ".join(plan.failures), plan)
        return plan

    monkeypatch.setattr(tolerance, "plan", scripted_plan)
    monkeypatch.setattr(tolerance, "clock_flights", lambda *args: (1.5e-4, None, {"0": 0.15}))
    model = SimpleNamespace(spec=SimpleNamespace(controller=SimpleNamespace(kp=5.0, kd=5.0, rate_hz=50.0)))
    with pytest.raises(PlanFailure) as failed:
        tolerance.plan_to_tolerance(model, None, None, 1e-4, ("mlm",), compare=False)
    plan = failed.value.plan
    assert plan.duration == 3.0  # the first round's
    record = plan.tolerance
    assert not record["met"] and record["flown_mm"] == pytest.approx(0.15)
    assert [r["model_bound_mm"] for r in record["rounds"]] == pytest.approx([0.1, 0.1 * 0.97 / 1.5])
    assert "Infeasible_Problem_Detected" in record["rounds"][1]["not_solved"]
    assert record["rounds"][1]["flown_mm"] is None
    assert any("0.06467 mm was not solved" in f for f in plan.failures)
    assert any("tolerance was not met" in f for f in plan.failures)


def test_the_clock_flights_stop_at_the_first_miss_only_when_asked(lift_crane, monkeypatch):
    """The uniform slowdown's search asks of each factor a yes or no (tolerance.uniform_factor): its flights stop at
    the first that misses. Without `stop_above`, or with one nothing misses, the figures are those of every flight."""
    from acroboter.planning import tolerance

    calls = []
    real = tolerance.certify
    monkeypatch.setattr(tolerance, "certify", lambda *a, **k: calls.append(a[-1]) or real(*a, **k))
    lift = quintic_lift(1.5)
    model, q0 = lift_crane.model, lift_crane.equilibrium(trajectory=lift, duration=lift.duration).q
    lower, upper, _ = model.spec.input_limits()
    args = (model, lift_crane.desired(), lift, q0, ("mlm", "penalty"), (lower, upper))
    full = tolerance.clock_flights(*args)
    assert calls == [("mlm", "penalty")] * len(tolerance.CLOCK_OFFSETS) and full[1] is None
    calls.clear()
    loose = tolerance.clock_flights(*args, stop_above=1.0)
    assert len(calls) == 2 * len(tolerance.CLOCK_OFFSETS) and loose == full
    calls.clear()
    worst, failure, by_offset = tolerance.clock_flights(*args, stop_above=1e-9)
    assert calls == [("mlm",)] and list(by_offset) == ["0"] and worst == by_offset["0"] * 1e-3 > 1e-9
