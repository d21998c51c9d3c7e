"""The crane's symbolic model in CasADi SX, derived from a spec.

M and c come from the energies T, U and the dissipation function D through Lagrange's equations;
nothing about their structure is written by hand. Time enters only through the signal vector s
and its two derivatives, so every time derivative follows from the chain rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..layout import Layout, build_layout
from ..spec import BodyThrust, BodyTorque, LevelTask, PositionTask, Spec, WinchTension, YawTask

AXIS_INDEX = {"u": 0, "v": 1, "w": 2}
# Heading of a body axis relative to the body's u axis, for the yaw servo-constraint.
AXIS_HEADING = {"u": 0.0, "v": np.pi / 2}


@dataclass
class BodySymbols:
    r: ca.SX
    axes: list[ca.SX]  # u, v, w
    r_dot: ca.SX
    axes_dot: list[ca.SX]

    def point(self, xi) -> ca.SX:
        return self.r + xi[0] * self.axes[0] + xi[1] * self.axes[1] + xi[2] * self.axes[2]


@dataclass
class SymbolicModel:
    """All model terms as SX expressions of the inputs (q, qd, s, sd, sdd)."""

    spec: Spec
    layout: Layout
    inputs: list[ca.SX]
    kinetic: ca.SX
    potential: ca.SX
    dissipation: ca.SX
    mass_matrix: ca.SX
    bias_forces: ca.SX
    phi: ca.SX
    phi_q: ca.SX
    phi_dot: ca.SX
    gamma: ca.SX
    sigma: ca.SX
    sigma_q: ca.SX
    sigma_dot: ca.SX
    gamma_s: ca.SX
    input_matrix: ca.SX


def _time_derivatives(expr, q, qd, s, sd, sdd):
    """expr(q, s) -> (J = d expr/dq, expr_dot, gamma) with expr_ddot = J qdd + gamma."""
    jac = ca.jacobian(expr, q)
    expr_dot = ca.jtimes(expr, q, qd) + ca.jtimes(expr, s, sd)
    gamma = ca.jtimes(expr_dot, q, qd) + ca.jtimes(expr_dot, s, sd) + ca.jtimes(expr_dot, sd, sdd)
    return jac, expr_dot, gamma


def build_symbolic_model(spec: Spec) -> SymbolicModel:
    layout = build_layout(spec)
    n, ns = layout.n, layout.n_signals
    q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
    s, sd, sdd = ca.SX.sym("s", ns), ca.SX.sym("sd", ns), ca.SX.sym("sdd", ns)

    bodies: dict[str, BodySymbols] = {}
    for body in spec.bodies:
        i = layout.body_offset[body.name]
        bodies[body.name] = BodySymbols(
            r=q[i : i + 3],
            axes=[q[i + 3 : i + 6], q[i + 6 : i + 9], q[i + 9 : i + 12]],
            r_dot=qd[i : i + 3],
            axes_dot=[qd[i + 3 : i + 6], qd[i + 6 : i + 9], qd[i + 9 : i + 12]],
        )

    def world_point(end: str) -> ca.SX:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            return bodies[body_name].point(spec.body(body_name).point(point_name))
        anchor = spec.anchor(end)
        if end in layout.anchor_signal:
            j = layout.anchor_signal[end]
            return s[j : j + 3]
        return ca.DM(anchor.position)

    # --- energies ------------------------------------------------------------------------------
    gravity = ca.DM(spec.gravity)
    kinetic, potential, dissipation = 0, 0, 0
    for body in spec.bodies:
        b = bodies[body.name]
        # T_rot = 1/2 sum_ij J_ij e_i'.e_j' with J = 1/2 tr(I_G) E - I_G (natural coordinates)
        inertia = np.array(body.inertia, dtype=float)
        j_matrix = 0.5 * np.trace(inertia) * np.eye(3) - inertia
        kinetic += 0.5 * body.mass * ca.dot(b.r_dot, b.r_dot)
        for a in range(3):
            for c in range(3):
                if j_matrix[a, c] != 0:
                    kinetic += 0.5 * j_matrix[a, c] * ca.dot(b.axes_dot[a], b.axes_dot[c])
        potential += -body.mass * ca.dot(gravity, b.r)
        dissipation += 0.5 * body.damping.translational * ca.dot(b.r_dot, b.r_dot)
        dissipation += 0.25 * body.damping.rotational * sum(ca.dot(e, e) for e in b.axes_dot)
    for cable in spec.cables:
        if cable.winch is not None:
            i = layout.winch_index[cable.name]
            kinetic += 0.5 * cable.winch.reflected_inertia * qd[i] ** 2

    # Lagrange: M qdd + c = Q with M = d2T/dqd2, c = (d/dq dT/dqd) qd - dT/dq + dU/dq + dD/dqd
    mass_matrix, _ = ca.hessian(kinetic, qd)
    dt_dqd = ca.gradient(kinetic, qd)
    bias_forces = (
        ca.mtimes(ca.jacobian(dt_dqd, q), qd)
        - ca.gradient(kinetic, q)
        + ca.gradient(potential, q)
        + ca.gradient(dissipation, qd)
    )

    # --- geometric constraints -----------------------------------------------------------------
    phi_rows = []
    for body in spec.bodies:
        u, v, w = bodies[body.name].axes
        phi_rows += [ca.dot(u, u) - 1, ca.dot(v, v) - 1, ca.dot(w, w) - 1, ca.dot(u, v), ca.dot(v, w), ca.dot(w, u)]
        if body.redundant_constraints:
            cross = w - ca.cross(u, v)
            phi_rows += [cross[0], cross[1], cross[2]]
    for cable in spec.cables:
        d = world_point(cable.ends[0]) - world_point(cable.ends[1])
        length = q[layout.winch_index[cable.name]] if cable.winch is not None else cable.length
        phi_rows.append(ca.dot(d, d) - length**2)
    phi = ca.vertcat(*phi_rows)
    phi_q, phi_dot, gamma = _time_derivatives(phi, q, qd, s, sd, sdd)

    # --- servo-constraints (the task) ----------------------------------------------------------
    p = layout.path_signal
    sigma_rows = []
    for task in spec.task:
        b = bodies[task.body]
        if isinstance(task, PositionTask):
            sigma_rows.append(b.point(task.point) - s[p : p + 3])
        elif isinstance(task, YawTask):
            axis = b.axes[AXIS_INDEX[task.axis]]
            heading = s[p + 3] + AXIS_HEADING[task.axis]
            sigma_rows.append(-ca.sin(heading) * axis[0] + ca.cos(heading) * axis[1])
        elif isinstance(task, LevelTask):
            axis = b.axes[AXIS_INDEX[task.axis]]
            sigma_rows += [axis[0], axis[1]]
    sigma = ca.vertcat(*sigma_rows)
    sigma_q, sigma_dot, gamma_s = _time_derivatives(sigma, q, qd, s, sd, sdd)

    # --- input matrix H(q): generalized force of each actuator --------------------------------
    columns = []
    for act in spec.actuators:
        col = ca.SX.zeros(n)
        if isinstance(act, WinchTension):
            col[layout.winch_index[act.cable]] = -1  # tension > 0 pulls the cable in
        elif isinstance(act, BodyTorque):
            b, i = bodies[act.body], layout.body_offset[act.body]
            torque = b.axes[AXIS_INDEX[act.axis]]  # unit torque about the body axis
            for k, e in enumerate(b.axes):  # virtual work n . delta_theta
                col[i + 3 + 3 * k : i + 6 + 3 * k] = 0.5 * ca.cross(torque, e)
        elif isinstance(act, BodyThrust):
            b, i = bodies[act.body], layout.body_offset[act.body]
            force = b.axes[AXIS_INDEX[act.axis]]
            weights = [1.0, *act.point]  # C(xi)^T f
            for k in range(4):
                if weights[k] != 0:
                    col[i + 3 * k : i + 3 * k + 3] = weights[k] * force
        columns.append(act.gain * col if act.gain != 1.0 else col)
    input_matrix = ca.horzcat(*columns)

    return SymbolicModel(
        spec=spec,
        layout=layout,
        inputs=[q, qd, s, sd, sdd],
        kinetic=kinetic,
        potential=potential,
        dissipation=dissipation,
        mass_matrix=mass_matrix,
        bias_forces=bias_forces,
        phi=phi,
        phi_q=phi_q,
        phi_dot=phi_dot,
        gamma=gamma,
        sigma=sigma,
        sigma_q=sigma_q,
        sigma_dot=sigma_dot,
        gamma_s=gamma_s,
        input_matrix=input_matrix,
    )
