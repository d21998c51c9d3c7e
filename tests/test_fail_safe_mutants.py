"""Suggested tests (mutation pass, issue 38). Uses test_fail_safe's recorded runs."""
from __future__ import annotations

import numpy as np
import pytest
import test_fail_safe
from test_fail_safe import FAULT_START, with_winch_bound

from acroboter.sim.fast_estimator import make_estimator
from acroboter.sim.sensing import ACCEPTED, COASTING, LOST

cases = test_fail_safe.cases  # its recorded runs and exported controllers (a module fixture)


def twins(case, fast, overrides=None, count=2):
    crane = case.crane
    sensing = crane.sensing({**case.sensing, **(overrides or {})})
    ests = [make_estimator(crane.model, crane.path, sensing, fast=fast) for _ in range(count)]
    for e in ests:
        e.reset(case.result.q[0])
    return ests


def run(est, case, ks, y=None):
    y = case.result.measurements if y is None else y
    for k in ks:
        est.update(y[k], case.result.time[k])
        est.applied(None)
    return est.status


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_coasting_boundaries_and_reacquisition(cases, fast):
    case = cases["penalty-d1"]
    (est,) = twins(case, fast, count=1)
    mc, y, t = est.checks.max_coast, case.result.measurements.copy(), case.result.time
    k0 = FAULT_START
    run(est, case, range(k0))
    y[k0 : k0 + mc, 0] = np.nan  # exactly max_coast rejected: coasting, never lost
    statuses = []
    for k in range(k0, k0 + mc + 1):
        statuses.append((est.update(y[k], t[k]), est.reason, est.rejected))
        est.applied(None)
    assert statuses[:-1] == [(COASTING, 1, 0)] * mc
    assert statuses[-1][0] == ACCEPTED  # the first good sample after max_coast rejections: gated, accepted
    k1 = k0 + mc + 20
    run(est, case, range(k0 + mc + 1, k1))
    y[k1 : k1 + mc + 1, 0] = np.nan  # max_coast + 1: lost on the last
    y[k1 + mc + 2, case.names.index("SU.r_x")] += 0.3  # the second good sample disagrees with the first
    out = []
    for k in range(k1, k1 + mc + 5):
        out.append((est.update(y[k], t[k]), est.reason))
        est.applied(None)
    assert [s for s, _ in out[:mc]] == [COASTING] * mc and out[mc][0] == LOST
    assert out[mc + 1] == (LOST, 5)  # one valid sample alone does not re-acquire
    assert out[mc + 2] == (LOST, 5)  # nor one that disagrees with the one before
    assert out[mc + 3] == (LOST, 5)  # nor the next (it disagrees with the jumped one)
    assert out[mc + 4][0] == ACCEPTED


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_the_gate_widens_and_the_rate_share_shrinks_while_coasting(cases, fast):
    case = cases["penalty-d1"]
    a, b = twins(case, fast)
    y, t, T = case.result.measurements.copy(), case.result.time, a.period
    k0 = FAULT_START
    for e in (a, b):
        run(e, case, range(k0))
    gate = a.checks.gate
    j = [i for i, n in enumerate(case.names) if n == "SU.r_z"][0]
    # a: not coasting, the sample 1.5 gates off: rejected (3); b: after 2 rejected samples (gate x 3): accepted
    bad = y[k0 + 2].copy()
    bad[j] += 1.5 * gate[j]
    run(a, case, range(k0, k0 + 2))
    assert a.update(bad, t[k0 + 2]) == COASTING and a.reason == 3
    y[k0 : k0 + 2, 0] = np.nan
    run(b, case, range(k0, k0 + 2), y)
    assert b.coasted == 2
    xf, vf = b._xf.copy(), b._vf.copy()
    assert b.update(bad, t[k0 + 2]) == ACCEPTED
    pred = b._pred[b.index]
    expect = np.max(np.abs(bad - pred) / (gate * 3.0))
    assert b.jump == pytest.approx(expect, rel=1e-9)
    # the rate's share of the innovation over 1 + coasted = 3 periods (acc = 0: applied(None))
    xp = xf + T * vf
    r = b._qm - xp
    vf_expect = vf + (b.beta / (T * 3.0)) * r
    np.testing.assert_allclose(b._vf, vf_expect, rtol=0, atol=1e-9)


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_a_nan_sample_is_reason_1_and_a_non_finite_estimate_goes_back_to_the_last_accepted(cases, fast):
    case = cases["penalty-d1"]
    (est,) = twins(case, fast, count=1)
    y, t = case.result.measurements.copy(), case.result.time
    k0 = FAULT_START
    run(est, case, range(k0))
    y[k0, 4] = np.nan
    assert est.update(y[k0], t[k0]) == COASTING and (est.reason, est.rejected) == (1, 4)
    est.applied(None)
    assert est.update(y[k0 + 1], t[k0 + 1]) == ACCEPTED
    good = est._qm.copy()
    est.applied(np.full(case.crane.layout.n, 1e200))  # finite, absurd: the prediction overflows
    assert est.update(y[k0 + 2], t[k0 + 2]) == LOST and est.reason == 6
    np.testing.assert_array_equal(est._qm, good)
    assert (est.qd == 0).all() and np.isfinite(est.q).all()


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_a_non_finite_command_is_no_command(cases, fast):
    case = cases["penalty-d1"]
    a, b = twins(case, fast)
    y, t = case.result.measurements, case.result.time
    n = case.crane.layout.n
    for k in range(FAULT_START + 5):
        a.update(y[k], t[k])
        b.update(y[k], t[k])
        if k >= FAULT_START:
            a.applied(np.full(n, np.nan))
            b.applied(None)
        else:
            a.applied(None)
            b.applied(None)
    np.testing.assert_array_equal(a.q, b.q)


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_a_sample_the_projection_cannot_take_leaves_the_prediction(cases, fast):
    case = cases["penalty-d1"]
    a, b = twins(case, fast, {"projection_iterations": 1})
    y, t = case.result.measurements.copy(), case.result.time
    k0 = FAULT_START
    for e in (a, b):
        run(e, case, range(k0))
    j = case.names.index("SU.r_z")
    bad, nan = y[k0].copy(), y[k0].copy()
    bad[j] += 0.5 * a.checks.gate[j]
    nan[0] = np.nan
    a.update(bad, t[k0])
    b.update(nan, t[k0])
    assert a.reason == 4, a.reason
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)


@pytest.mark.parametrize("fast", [False, True], ids=["python", "c"])
def test_reinit_takes_the_next_sample_without_a_gate(cases, fast):
    case = cases["penalty-d1"]
    (est,) = twins(case, fast, count=1)
    run(est, case, range(100))
    est.reinit()
    assert est.update(case.result.measurements[130], case.result.time[130]) == ACCEPTED  # the crane moved meanwhile


def test_c_init_refuses_when_no_static_command(cases, tmp_path):
    case = cases["penalty-d1"]
    c = with_winch_bound(case, tmp_path, 20.0)
    c.state[:] = 0
    assert c.init(case.result.q[0], case.signals[0]) == 8
    assert c.step(case.result.measurements[0], 0.0, case.signals[0]) == 1


def test_a_failed_init_leaves_the_struct_uninitialised(cases):
    case = cases["penalty-d1"]
    c = case.c
    c.state[:] = 0
    flipped = case.result.q[0].copy()
    for offset in case.crane.layout.body_offset.values():
        flipped[offset + 9 : offset + 12] *= -1.0
    assert c.init(flipped, case.signals[0]) == 7
    assert (c.state == 0).all()
    c.u[:] = 123.0
    assert c.step(case.result.measurements[0], 0.0, case.signals[0]) == 1 and (c.u == 123.0).all()


def test_reset_restores_the_static_safe_command(cases, tmp_path):
    case = cases["penalty-d1"]
    static = float(np.max(case.result.u[0, :3]))
    c = with_winch_bound(case, tmp_path, static + 0.5)
    y0 = case.result.measurements[0].copy()
    y0[case.names.index("SU.r_z")] -= 0.1
    assert c.init(case.result.q[0], case.signals[0]) == 0
    assert c.step(y0, 0.0, case.signals[0]) == 6
    u_static = c.u.copy()
    run = zip(case.result.time, case.result.measurements, strict=True)
    codes = [c.step(y, t, case.signals[k]) for k, (t, y) in enumerate(run)]
    assert 0 in codes and not np.array_equal(c.u, u_static)
    assert c.reset() == 0
    assert c.step(y0, 0.0, case.signals[0]) == 6
    np.testing.assert_array_equal(c.u, u_static)


def test_beyond_the_bound_c_is_python(cases, tmp_path):
    case = cases["penalty-d1"]
    bound = float(np.round(np.sort(case.result.u[:, :3].ravel())[-40], 6))
    c = with_winch_bound(case, tmp_path, bound)
    python = case.python
    try:
        python.high[:3] = bound
        u_c, codes_c = np.zeros_like(case.result.u), []
        assert c.init(case.result.q[0], case.signals[0]) == 0
        for k, (t, y) in enumerate(zip(case.result.time, case.result.measurements, strict=True)):
            codes_c.append(c.step(y, t, case.signals[k]))
            u_c[k] = c.u
        u_py, codes_py = case.replay(case.result.measurements, "python")
    finally:
        python.high[:] = case.high
    assert 6 in codes_c and codes_c == codes_py.tolist()
    assert (np.abs(u_c - u_py) / np.maximum(np.abs(u_py), 1)).max() <= 1e-6


def test_the_integral_the_safe_command_and_the_applied_acceleration_through_a_loss(cases):
    case = cases["penalty-d1"]
    py, est = case.python, case.python.estimator
    mc = case.max_coast
    y = case.result.measurements.copy()
    y[FAULT_START : FAULT_START + mc + 1, 0] = np.nan  # coasting, then lost on the last
    assert py.init(case.result.q[0]) == 0
    codes, us, zs = [], [], []
    for k, t in enumerate(case.result.time):
        codes.append(py.step(y[k], t))
        us.append(py.u.copy())
        zs.append(py.controller.integral.copy())
        if codes[-1] in (3, 5):
            assert (est._acc[(est._k - 1) % (est.delay + 1)] == 0).all()  # no command: no acceleration
    codes = np.array(codes)
    assert 5 in codes and 4 in codes
    for k in np.nonzero(codes == 4)[0]:
        np.testing.assert_array_equal(zs[k], zs[k - 1])  # z held over a coasted period
        assert not np.array_equal(us[k], us[k - 1])  # a command computed from the prediction, not the safe one
    for k in np.nonzero(codes == 5)[0]:
        np.testing.assert_array_equal(us[k], us[k - 1])  # the safe command: the last one computed
    after = int(np.nonzero(codes == 5)[0].max()) + 1
    assert codes[after] == 0
    np.testing.assert_array_equal(zs[after], zs[after - 1])  # nor over the period that ends at re-acquisition
    u_c, codes_c = case.replay(y, "c")
    assert codes_c.tolist() == codes.tolist()
    assert (np.abs(u_c - np.array(us)) / np.maximum(np.abs(np.array(us)), 1)).max() <= 1e-6
