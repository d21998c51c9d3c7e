"""The ideal motion's dynamics as CasADi functions, from the spec's symbolic model (acroboter.codegen.symbolic).

On the ideal motion every servo-constraint holds exactly (σ ≡ 0): MLM's system

    M q̈ + c = H u − φ_qᵀ λ,   φ_q q̈ = −ρ,   σ_q q̈ = −ρ_s

solved for (q̈, λ, u) at a state (q, q̇) and the path's signals. It is square when there are as many inputs
as servo-constraints; the unactuated part of q (the connector's swing) is then internal dynamics, known only
by integrating q̈. ρ and ρ_s carry Baumgarte terms (the spec's Ω, μ and k_P, k_D) that keep an integrated
state on the constraints; on the exact motion they are zero.

With more inputs than servo-constraints (the four-cable crane: seven inputs, six servo-constraints) the
motion is still unique but the inputs are not: l − k of them (the spare inputs) are an internal force, the
cables pulling against each other. They are then inputs of the function: the system is solved for the
other inputs with the spare ones given (moved to the right-hand side), and the retiming chooses them as
decision variables, one set per place it bounds the inputs. The spare inputs are the ones the null space of
the system moves most, picked one by one at the static start (`spare_inputs`), so that the rest stays square
and regular there.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..codegen.solver_terms import (
    constant_inverse_mass,
    independent_rows,
    mlm_bounded_terms,
    servo_and_constraint_rates,
)
from ..codegen.symbolic import build_symbolic_model
from ..model.controller_parameters import runtime_size
from ..model.spec import Spec
from ..model.spec_checks import task_components


class PlanningError(ValueError):
    """A retiming that cannot be set up or has no solution: the message names the cause and what to change."""


class SolveFailed(PlanningError):
    """IPOPT found no timing: `status` is what it said (its status and iterations). The message's advice is for a
    plan from rest; a re-solve from a carried swing (acroboter.planning.edges) quotes the status alone."""

    def __init__(self, status: str, uniform_duration: float):
        super().__init__(f"the time-optimal problem was not solved ({status}); the best uniform slowdown "
                         f"({uniform_duration:.4g} s) is feasible: try more --intervals or a larger margin")
        self.status = status


def check_retimable(name: str, layout) -> None:
    """PlanningError for a crane the retiming cannot take (before any work: `plan` calls it first): fewer inputs than
    servo-constraints (no ideal motion), or more than one beyond them (it chooses one internal force)."""
    if layout.l < layout.k:
        raise PlanningError(f"spec '{name}': {layout.l} inputs for {layout.k} servo-constraints; the retiming "
                            "needs at least as many inputs as servo-constraints (the ideal motion then exists)")
    if layout.l - layout.k > 1:
        raise PlanningError(f"spec '{name}': {layout.l - layout.k} inputs beyond the servo-constraints; the "
                            "retiming handles one (an internal force such as the four-cable crane's)")


class IdealDynamics:
    """`function(q, qd, s, sd, sdd, spare) -> (qdd, u)`: the ideal motion's accelerations and inputs
    (casadi.Function); `spare` (l − k values, empty for a square system) are the inputs `spare_index` names."""

    def __init__(self, spec: Spec, q0: np.ndarray | None = None):
        model = build_symbolic_model(spec)
        lay = model.layout
        check_retimable(spec.name, lay)
        self.layout = lay
        q, qd, s, sd, sdd = model.inputs
        c = spec.controller
        # the ideal motion keeps φ = 0 as the plant does (its Baumgarte numbers) and σ = 0 as the controller would
        rho, rho_s = servo_and_constraint_rates(model, kp=c.kp, kd=c.kd, ki=0.0, z=0.0,
                                                omega=spec.simulation.baumgarte_omega,
                                                mu=spec.simulation.baumgarte_zeta)
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
        m = len(rows)
        self.spare_index: list[int] = []
        self.spare_signs = np.zeros(lay.l)
        if lay.l > lay.k:
            if q0 is None:
                raise PlanningError(f"spec '{spec.name}' has a spare input: the static start q0 is needed to choose it")
            zero = np.zeros(lay.n_signals)
            at_rest = np.asarray(terms(q0, np.zeros(lay.n), zero, zero, zero)[0])
            self.spare_index = spare_inputs(at_rest, m, lay.l - lay.k)
        spare_cols = [m + i for i in self.spare_index]
        free = [j for j in range(m + lay.l) if j not in spare_cols]
        mq, mqd = ca.MX.sym("q", lay.n), ca.MX.sym("qd", lay.n)
        ms, msd, msdd = (ca.MX.sym(name, lay.n_signals) for name in ("s", "sd", "sdd"))
        a, b, minv_c, minv_w = terms(mq, mqd, ms, msd, msdd)
        direction = ca.MX.zeros(lay.l, len(spare_cols))
        if spare_cols:
            # the spare input at 0 (its value then shifts u along `direction`, and q̈ not at all)
            solved = ca.solve(a[:, free], ca.horzcat(b, -a[:, spare_cols]))
            y, dy = ca.MX.zeros(m + lay.l), ca.MX.zeros(m + lay.l, len(spare_cols))
            y[free], dy[free, :] = solved[:, 0], solved[:, 1:]
            dy[spare_cols, :] = ca.MX.eye(len(spare_cols))
            direction = dy[m:, :]
        else:
            y = ca.solve(a, b)
        qdd = -minv_c - ca.mtimes(minv_w, y)
        self.function = ca.Function("ideal", [mq, mqd, ms, msd, msdd], [qdd, y[m:], direction],
                                    ["q", "qd", "s", "sd", "sdd"], ["qdd", "u", "direction"])
        self.spares = len(spare_cols)
        if spare_cols:  # the signs of u's change per unit of the spare input, at rest (kept by the retiming)
            d0 = np.asarray(self.function(q0, np.zeros(lay.n), zero, zero, zero)[2]).ravel()
            self.spare_signs = np.where(np.abs(d0) > 1e-9 * np.abs(d0).max(), np.sign(d0), 0.0)
            self.spare_at_rest = np.abs(d0)
        self.servo = ca.Function("servo", [q, s], [model.sigma])
        # E = σ_q P H: the servo-constraint accelerations per unit of input on the constraint manifold (a run-time
        # parameter vector is its builder's argument; E does not depend on it). A sampled controller holds u over a
        # period while the ideal u moves on: E u̇ drives its lag (acroboter.planning.servo_lag).
        e_map = mlm_bounded_terms(model, ca.SX.sym("p", runtime_size(lay.k)))["servo_map"]
        self.servo_map = ca.Function("servo_map", [q, s], [e_map])
        rows = task_components(spec)  # the position task's x, y ("horizontal") and z ("height") rows
        self.position_rows = rows["horizontal"] + rows["height"]
        self.constraints = ca.Function("constraints", [q, s], [model.phi])


def spare_inputs(system: np.ndarray, m: int, count: int) -> list[int]:
    """The `count` inputs to give (the spare ones) for the system [multipliers (m) | inputs] at rest: one by one,
    the input the system's null space moves most (the internal force's direction), among those left; the
    remaining columns must then be regular (else PlanningError: the extra inputs are not an internal force)."""
    chosen: list[int] = []
    a = np.asarray(system, float)
    for _ in range(count):
        cols = [j for j in range(a.shape[1]) if j - m not in chosen]
        _, _, vt = np.linalg.svd(a[:, cols])
        null = vt[-1]  # the null direction: the reduced system has one column more than it has rows
        weights = [abs(null[cols.index(m + i)]) if m + i in cols else 0.0 for i in range(a.shape[1] - m)]
        best = max(range(len(weights)), key=lambda i: (round(weights[i], 12), i))
        chosen.append(best)
    rest = a[:, [j for j in range(a.shape[1]) if j - m not in chosen]]
    if np.linalg.cond(rest) > 1e10:
        raise PlanningError(f"the inputs beyond the servo-constraints ({count}) are not an internal force at the "
                            "static start (the rest of the system is singular): the retiming cannot choose them")
    return sorted(chosen)


def rk4_step(dynamics: IdealDynamics, geometry, substeps: int) -> ca.Function:
    """One interval of h seconds with the path acceleration τ̈(t) = a + j·t (t from the interval's start: a held
    when the jerk j is 0, linear when the timing is smooth): state x = (q, q̇, τ, τ̇), `substeps` RK4 steps (τ is
    a cubic in t, which RK4 integrates exactly). Returns the end state, the inputs at the start of each substep
    (n_inputs x substeps; with a spare input, at its value 0) and their change per unit of the spare input
    (n_inputs x substeps, 0 without one), the same two at the interval's end with its τ̈ (n_inputs x 1 each), and
    the position rows of E u̇ over each substep (3 x substeps: the servo-constraint jerk a held input misses)."""
    n = dynamics.layout.n
    x = ca.MX.sym("x", 2 * n + 2)
    a = ca.MX.sym("tau_dd")
    jerk = ca.MX.sym("tau_ddd")
    h = ca.MX.sym("h")

    def rate(state, acc):
        q, qd, tau, tau_d = state[:n], state[n : 2 * n], state[2 * n], state[2 * n + 1]
        g, d1, d2 = geometry.function(tau)
        qdd, u, direction = dynamics.function(q, qd, g, d1 * tau_d, d2 * tau_d**2 + d1 * acc)
        return ca.vertcat(qd, qdd, tau_d, acc), u, direction

    dt = h / substeps
    state, inputs, directions, maps = x, [], [], []
    for i in range(substeps):
        start = a + jerk * (i * dt)
        k1, u, direction = rate(state, start)
        inputs.append(u)
        directions.append(direction if dynamics.spares else ca.MX.zeros(u.shape))
        maps.append(dynamics.servo_map(state[:n], geometry.function(state[2 * n])[0]))
        k2 = rate(state + dt / 2 * k1, start + jerk * (dt / 2))[0]
        k3 = rate(state + dt / 2 * k2, start + jerk * (dt / 2))[0]
        k4 = rate(state + dt * k3, start + jerk * dt)[0]
        state = state + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    # the inputs at the interval's end with its own τ̈ (the left limit at the next node, where a held τ̈ jumps): a
    # bang-bang timing's input peaks there, and the next interval's start sees it only after the jump
    _, u_end, direction_end = rate(state, a + jerk * h)
    # the position rows of E u̇ over each RK4 step (E at its start; the spare input's direction moves no servo-
    # constraint, so its value 0 serves): what a controller holding u over a period falls behind by
    ahead = [*inputs[1:], u_end]
    rows = dynamics.position_rows
    servo_rate = ca.horzcat(*[ca.mtimes(e[rows, :], (nxt - now) / dt) for e, now, nxt in zip(maps, inputs, ahead,
                                                                                                strict=True)])
    return ca.Function("interval", [x, a, jerk, h], [state, ca.horzcat(*inputs), ca.horzcat(*directions), u_end,
                                                     direction_end if dynamics.spares else ca.MX.zeros(u_end.shape),
                                                     servo_rate],
                       ["x", "tau_dd", "tau_ddd", "h"],
                       ["x_end", "u", "direction", "u_end", "direction_end", "servo_rate"])


def inputs_at(dynamics: IdealDynamics, geometry, x, a):
    """The ideal inputs at a state x = (q, q̇, τ, τ̇) with path acceleration a (symbolic or numeric), and their
    change per unit of the spare input: (u, direction)."""
    n = dynamics.layout.n
    q, qd, tau, tau_d = x[:n], x[n : 2 * n], x[2 * n], x[2 * n + 1]
    g, d1, d2 = geometry.function(tau)
    _, u, direction = dynamics.function(q, qd, g, d1 * tau_d, d2 * tau_d**2 + d1 * a)
    return u, direction if dynamics.spares else ca.DM.zeros(u.shape)
