"""How far a sampled controller lags behind a smooth timing: the model behind `plan --tolerance`.

Every method's servo law drives the servo-constraint error σ as σ̈ + 2kd σ̇ + kp² σ = 0 (docs/controller.md), with
σ̈ = E u − e, E = σ_q P H (the servo-constraint accelerations per unit of input, the constraint reactions taken
out). But it is sampled: at t_k it commands the input the path asks for at t_k and holds it for T = 1/rate_hz,
while the ideal input moves on. Over a period the servo accelerations then fall short by E u̇ (t − t_k), on
average E u̇ T/2, and the tracked point's error e (the position rows of σ) obeys

    ë + 2kd ė + kp² e = −(T/2)·E u̇        (per axis of the tracked point)

(on a vertical lift, where nothing swings, E u̇ is the tracked point's jerk j: held at a constant jerk, e =
−j·T/(2kp²), 0.4 mm at 1 m/s³ on the default crane, kp = kd = 5 1/s, 50 Hz). Where the connector swings, the ideal
inputs move with the swing too, and E u̇ carries it (on a horizontal edge of the default crane, swinging and with a
90° yaw turn, MLM flew the bound's 0.1 mm at 0.0977 and 0.0973 mm). Measured against flights of the default crane's
0.1 m lift on quintic timings of 0.9-3 s (MLM, penalty, iterative-3 alike), the model gave 0.7245, 0.4427, 0.3351,
0.2063, 0.1182, 0.0398 mm where the flights gave 0.7056, 0.4253, 0.3191, 0.1932, 0.1081, 0.0364 mm: 3-9 % above
(2026-12-06). It is MLM's servo law; the penalty methods add an error of their own on swinging paths
(docs/planning.md). A timing whose acceleration jumps (σ̈ held, bang-bang) has impulses of E u̇, which this model
does not take: the tolerance asks for a smooth timing (σ̈ continuous, acroboter.planning.retiming). What the model
leaves out (the plant's motion between samples, the sampled feedback) the certificate measures:
acroboter.planning.tolerance narrows the model's bound by what the flights show.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

# The lag model's RK4 steps: the fastest pole times the step at most this.
LAG_STEP_RATE = 0.25


def lag_step(kp: float, kd: float, period: float, substeps: int) -> ca.Function:
    """One interval of the lag model: z = (e, ė) (6: x, y, z), its drive E u̇ (3, held over the interval; on a
    lift the tracked point's jerk), h seconds in `substeps` RK4 steps -> z at the interval's end, and the error e
    at the end of every RK4 step (3 x substeps: its peak may fall between the nodes)."""
    z = ca.MX.sym("z", 6)
    jerk = ca.MX.sym("jerk", 3)
    h = ca.MX.sym("h")

    def rate(state):
        e, ed = state[:3], state[3:]
        return ca.vertcat(ed, -kp * kp * e - 2.0 * kd * ed - 0.5 * period * jerk)

    dt = h / substeps
    state, errors = z, []
    for _ in range(substeps):
        k1 = rate(state)
        k2 = rate(state + dt / 2 * k1)
        k3 = rate(state + dt / 2 * k2)
        k4 = rate(state + dt * k3)
        state = state + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        errors.append(state[:3])
    return ca.Function("servo_lag", [z, jerk, h], [state, ca.horzcat(*errors)], ["z", "jerk", "h"],
                       ["z_end", "errors"])


def lag_substeps(h: float, kp: float, kd: float, at_least: int = 1) -> int:
    """RK4 steps over an interval of h seconds that keep the model's fastest pole p times the step within
    LAG_STEP_RATE (RK4's error then ~1e-5 of the lag)."""
    fastest = kd + math.sqrt(abs(kd * kd - kp * kp)) if kd >= kp else kp  # |pole| of s² + 2kd s + kp²
    return max(at_least, int(math.ceil(h * fastest / LAG_STEP_RATE)))


def predicted_error(times: np.ndarray, jerk: np.ndarray, kp: float, kd: float, period: float,
                    settle_s: float = 2.0) -> float:
    """The model's largest error (m) along a timing whose drive E u̇ (on a lift: the tracked point's jerk) is
    `jerk` (samples x 3) at `times` (linear in between: scipy's lsim), and `settle_s` of rest after it (the lag
    dies out then)."""
    from scipy import signal

    times, jerk = np.asarray(times, float), np.asarray(jerk, float)
    grid = np.arange(0.0, times[-1] + settle_s, 1e-3)  # lsim takes a uniform grid
    drive = np.column_stack([np.interp(grid, times, jerk[:, c], right=0.0) for c in range(3)])
    system = signal.lti([1.0], [1.0, 2.0 * kd, kp * kp])
    errors = np.column_stack([signal.lsim(system, -0.5 * period * drive[:, c], grid)[1] for c in range(3)])
    return float(np.linalg.norm(errors, axis=1).max())


# The lag model's error is bounded after a phase ends too (an underdamped servo law overshoots after the drive
# stops; a lag still growing at the end peaks after it), at these times after the end (s): dense at first, where the
# free response of a critically damped law at kp = 5 1/s peaks (within 1/kp), then to 1 s.
LAG_SETTLE_TIMES_S = (0.025, 0.05, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0)
# The fewest RK4 steps of the lag model over each of its settling steps after the path.
LAG_SUBSTEPS = 4
# A phase that is not the path's last leaves its free lag response within this share of the bound: the next phase
# inherits that lag (acroboter.planning.edges carries it), and its own lag adds to it. Measured 2026-12-07 on a drawn
# three-edge path (tools/plan_fuzz.py, seed 0): with the whole bound, edge 2 ended at e = 0.0987 mm still growing
# at 0.092 mm/s (its free response peaking at 0.1001 mm, between the old settle samples), and edge 3 had no timing
# (IPOPT: Infeasible_Problem_Detected) whose lag stayed within 0.1 mm.
CORNER_LAG_SHARE = 0.5


def lag_bounds(opti, lag: tuple, servo_rate, steps, substeps: int, lag_substeps_each: int, z0: np.ndarray,
               corner_share: float = 1.0):
    """The lag model's constraints on a retiming problem (`opti`; `lag` = (bound m, kp, kd, period s)), driven by
    E u̇, the servo-constraint jerk a held input misses (rk4_step's `servo_rate`, one value per RK4 step of the ideal
    motion; `steps`: the problem's interval lengths, `substeps` RK4 steps each), from the lag state z0 (the phase
    before's, on a rest-to-rest path: the lags of a braking and an accelerating edge add up at a corner): its error
    within the bound at the end of each of its own `lag_substeps_each` RK4 steps per step (lag_substeps), and its free
    response after the end within `corner_share` of it at LAG_SETTLE_TIMES_S (CORNER_LAG_SHARE where a phase follows).
    Returns the lag state at the end (the next edge's start)."""
    bound, kp, kd, period = lag
    dts = ca.horzcat(*[ca.repmat(steps[i] / substeps, 1, substeps) for i in range(steps.shape[1])])
    step = lag_step(kp, kd, period, lag_substeps_each)
    Z, errors = step.mapaccum(servo_rate.shape[1])(ca.DM(z0), servo_rate, dts)
    after = np.diff(np.concatenate([[0.0], LAG_SETTLE_TIMES_S]))
    settling = lag_step(kp, kd, period, lag_substeps(float(after.max()), kp, kd, LAG_SUBSTEPS))
    _, settle = settling.mapaccum(after.size)(Z[:, -1], ca.DM.zeros(3, after.size), ca.DM(after[None, :]))
    for k in range(errors.shape[1]):  # scaled: bound² (1e-8 m²) is IPOPT's tolerance
        opti.subject_to(ca.sumsqr(errors[:, k] / bound) <= 1.0)
    for k in range(settle.shape[1]):
        opti.subject_to(ca.sumsqr(settle[:, k] / (corner_share * bound)) <= 1.0)
    return Z[:, -1]
