"""The ideal motion's dynamics as CasADi functions, from the spec's symbolic model (acroboter.codegen.symbolic).

On the ideal motion every servo-constraint holds exactly (σ ≡ 0): MLM's system

    M q̈ + c = H u − φ_qᵀ λ,   φ_q q̈ = −ρ,   σ_q q̈ = −ρ_s

solved for (q̈, λ, u) at a state (q, q̇) and the path's signals. It is square when there are as many inputs
as servo-constraints; the unactuated part of q (the connector's swing) is then internal dynamics, known only
by integrating q̈. ρ and ρ_s carry Baumgarte terms (the spec's Ω, μ and k_P, k_D) that keep an integrated
state on the constraints; on the exact motion they are zero.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..codegen.structured import (
    PARAMS,
    constant_inverse_mass,
    independent_rows,
    servo_and_constraint_rates,
)
from ..codegen.symbolic import build_symbolic_model
from ..model.spec import Spec


class PlanningError(ValueError):
    """A retiming that cannot be set up or has no solution: the message names the cause and what to change."""


class IdealDynamics:
    """`function(q, qd, s, sd, sdd) -> (qdd, u)`: the ideal motion's accelerations and inputs (casadi.Function)."""

    def __init__(self, spec: Spec):
        model = build_symbolic_model(spec)
        lay = model.layout
        if lay.k != lay.l:
            raise PlanningError(f"spec '{spec.name}': {lay.l} inputs for {lay.k} servo-constraints; the retiming "
                                "needs as many inputs as servo-constraints (the inverse dynamics then have one "
                                "solution)")
        self.layout = lay
        q, qd, s, sd, sdd = model.inputs
        c = spec.controller
        params = np.zeros(len(PARAMS) + lay.k)
        params[[0, 1, 4, 5]] = c.kp, c.kd, spec.simulation.baumgarte_omega, spec.simulation.baumgarte_zeta
        rho, rho_s = servo_and_constraint_rates(model, ca.DM(params))
        minv = constant_inverse_mass(model)
        rows = independent_rows(model)
        w = ca.horzcat(model.phi_q[rows, :].T, -model.input_matrix)
        cmat = ca.vertcat(model.phi_q[rows, :], model.sigma_q)
        schur = ca.mtimes(cmat, ca.mtimes(minv, w))
        rhs = ca.vertcat(rho[rows], rho_s) - ca.mtimes(cmat, ca.mtimes(minv, model.bias_forces))
        # the matrices in SX (their entries are short expressions of q, q̇), the solve in MX: its derivatives are
        # further solves with the same matrix, not a symbolic QR of 22 x 22 expressions differentiated twice
        terms = ca.Function("ideal_terms", [q, qd, s, sd, sdd],
                            [schur, rhs, ca.mtimes(minv, model.bias_forces), ca.mtimes(minv, w)])
        mq, mqd = ca.MX.sym("q", lay.n), ca.MX.sym("qd", lay.n)
        ms, msd, msdd = (ca.MX.sym(name, lay.n_signals) for name in ("s", "sd", "sdd"))
        a, b, minv_c, minv_w = terms(mq, mqd, ms, msd, msdd)
        y = ca.solve(a, b)
        qdd = -minv_c - ca.mtimes(minv_w, y)
        self.function = ca.Function("ideal", [mq, mqd, ms, msd, msdd], [qdd, y[len(rows):]],
                                    ["q", "qd", "s", "sd", "sdd"], ["qdd", "u"])
        self.servo = ca.Function("servo", [q, s], [model.sigma])
        self.constraints = ca.Function("constraints", [q, s], [model.phi])


def rk4_step(dynamics: IdealDynamics, geometry, substeps: int) -> ca.Function:
    """One interval of h seconds with the path acceleration τ̈ held: state x = (q, q̇, τ, τ̇), `substeps`
    RK4 steps. Returns the end state and the inputs at the start of each substep (n_inputs x substeps)."""
    n = dynamics.layout.n
    x = ca.MX.sym("x", 2 * n + 2)
    a = ca.MX.sym("tau_dd")
    h = ca.MX.sym("h")

    def rate(state):
        q, qd, tau, tau_d = state[:n], state[n : 2 * n], state[2 * n], state[2 * n + 1]
        g, d1, d2 = geometry.function(tau)
        qdd, u = dynamics.function(q, qd, g, d1 * tau_d, d2 * tau_d**2 + d1 * a)
        return ca.vertcat(qd, qdd, tau_d, a), u

    dt = h / substeps
    state, inputs = x, []
    for _ in range(substeps):
        k1, u = rate(state)
        inputs.append(u)
        k2, _ = rate(state + dt / 2 * k1)
        k3, _ = rate(state + dt / 2 * k2)
        k4, _ = rate(state + dt * k3)
        state = state + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("interval", [x, a, h], [state, ca.horzcat(*inputs)], ["x", "tau_dd", "h"], ["x_end", "u"])


def inputs_at(dynamics: IdealDynamics, geometry, x, a) -> ca.Function | ca.MX:
    """The ideal inputs at a state x = (q, q̇, τ, τ̇) with path acceleration a (symbolic or numeric)."""
    n = dynamics.layout.n
    q, qd, tau, tau_d = x[:n], x[n : 2 * n], x[2 * n], x[2 * n + 1]
    g, d1, d2 = geometry.function(tau)
    return dynamics.function(q, qd, g, d1 * tau_d, d2 * tau_d**2 + d1 * a)[1]
