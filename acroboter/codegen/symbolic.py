"""The crane's symbolic model in CasADi SX, derived from a spec.

M and c come from the energies T, U and the dissipation function D through Lagrange's equations;
nothing about their structure is written by hand. Time enters only through the signal vector s
and its two derivatives, so every time derivative follows from the chain rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..model.layout import Layout, build_layout
from ..model.physical import INERTIA_ENTRIES, parameter_names
from ..model.spec import BodyThrust, BodyTorque, LevelTask, PositionTask, Spec, WinchTension, YawTask

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
    # The physical parameters (acroboter.model.physical) the terms depend on as symbols: a parametric model
    # (the plant's) has one per name, the controller's none (its numbers are folded in).
    parameters: ca.SX
    parameter_names: list[str]
    fixed_lengths: dict[str, ca.SX | float]  # fixed-length cable name -> its length


def _time_derivatives(expr, q, qd, s, sd, sdd):
    """expr(q, s) -> (J = d expr/dq, expr_dot, gamma) with expr_ddot = J qdd + gamma."""
    jac = ca.jacobian(expr, q)
    expr_dot = ca.jtimes(expr, q, qd) + ca.jtimes(expr, s, sd)
    gamma = ca.jtimes(expr_dot, q, qd) + ca.jtimes(expr_dot, s, sd) + ca.jtimes(expr_dot, sd, sdd)
    return jac, expr_dot, gamma


def build_symbolic_model(spec: Spec, parametric: bool = False) -> SymbolicModel:
    """The model terms of `spec`: with the spec's numbers as constants, or (parametric) with every
    physical parameter (acroboter.model.physical.parameter_names) a symbol of the vector `parameters`."""
    terms = _Terms(spec, parametric)
    q, qd, s, sd, sdd = terms.inputs
    kinetic, potential, dissipation, fixed_lengths = terms.energies()
    # Lagrange: M qdd + c = Q with M = d2T/dqd2, c = (d/dq dT/dqd) qd - dT/dq + dU/dq + dD/dqd
    mass_matrix, _ = ca.hessian(kinetic, qd)
    dt_dqd = ca.gradient(kinetic, qd)
    bias_forces = (
        ca.mtimes(ca.jacobian(dt_dqd, q), qd)
        - ca.gradient(kinetic, q)
        + ca.gradient(potential, q)
        + ca.gradient(dissipation, qd)
    )
    phi = terms.geometric_constraints(fixed_lengths)
    phi_q, phi_dot, gamma = _time_derivatives(phi, q, qd, s, sd, sdd)
    sigma = terms.servo_constraints()
    sigma_q, sigma_dot, gamma_s = _time_derivatives(sigma, q, qd, s, sd, sdd)
    return SymbolicModel(
        spec=spec,
        layout=terms.layout,
        inputs=terms.inputs,
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
        input_matrix=terms.input_matrix(),
        parameters=terms.theta,
        parameter_names=terms.names,
        fixed_lengths=fixed_lengths,
    )


class _Terms:
    """The symbols of one spec's model (q, q̇, the path signals s, ṡ, s̈, the physical parameters θ) and the
    terms built from them: the energies, the geometric and servo-constraints, the input matrix."""

    def __init__(self, spec: Spec, parametric: bool):
        self.spec, self.parametric = spec, parametric
        self.layout = layout = build_layout(spec)
        n, ns = layout.n, layout.n_signals
        q, qd = ca.SX.sym("q", n), ca.SX.sym("qd", n)
        self.inputs = [q, qd, ca.SX.sym("s", ns), ca.SX.sym("sd", ns), ca.SX.sym("sdd", ns)]
        self.names = parameter_names(spec) if parametric else []
        self.theta = ca.SX.sym("plant_params", len(self.names))
        self.index = {name: i for i, name in enumerate(self.names)}
        self.bodies: dict[str, BodySymbols] = {}
        for body in spec.bodies:
            i = layout.body_offset[body.name]
            self.bodies[body.name] = BodySymbols(
                r=q[i : i + 3],
                axes=[q[i + 3 : i + 6], q[i + 6 : i + 9], q[i + 9 : i + 12]],
                r_dot=qd[i : i + 3],
                axes_dot=[qd[i + 3 : i + 6], qd[i + 6 : i + 9], qd[i + 9 : i + 12]],
            )

    def value(self, name: str, nominal: float):
        """The parameter's symbol in a parametric model, else the spec's number (folded in as before)."""
        return self.theta[self.index[name]] if self.parametric else nominal

    def body_point(self, body, point: str) -> list:
        xyz = body.point(point)
        return [self.value(f"{body.name}.points.{point}.{c}", xyz[k]) for k, c in enumerate("xyz")]

    def world_point(self, end: str) -> ca.SX:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            return self.bodies[body_name].point(self.body_point(self.spec.body(body_name), point_name))
        anchor = self.spec.anchor(end)
        if end in self.layout.anchor_signal:
            j = self.layout.anchor_signal[end]
            return self.inputs[2][j : j + 3]
        return ca.DM(anchor.position)

    def energies(self) -> tuple:
        """(T, U, D, fixed lengths): the kinetic energy (bodies and winch drums), the gravity potential, the
        Rayleigh dissipation, and each fixed-length cable's length (a number or θ's symbol)."""
        spec, value, qd = self.spec, self.value, self.inputs[1]
        theta, index = self.theta, self.index
        gravity = ca.vertcat(*[theta[index[f"gravity.{c}"]] for c in "xyz"]) if self.parametric else ca.DM(spec.gravity)
        kinetic, potential, dissipation = 0, 0, 0
        for body in spec.bodies:
            b = self.bodies[body.name]
            # T_rot = 1/2 sum_ij J_ij e_i'.e_j' with J = 1/2 tr(I_G) E - I_G (natural coordinates)
            j_matrix = _axes_inertia(body, value) if self.parametric else (
                0.5 * np.trace(np.array(body.inertia, dtype=float)) * np.eye(3) - np.array(body.inertia, dtype=float))
            mass = value(f"{body.name}.mass", body.mass)
            kinetic += 0.5 * mass * ca.dot(b.r_dot, b.r_dot)
            for a in range(3):
                for c in range(3):
                    if not _is_zero(j_matrix[a][c]):
                        kinetic += 0.5 * j_matrix[a][c] * ca.dot(b.axes_dot[a], b.axes_dot[c])
            potential += -mass * ca.dot(gravity, b.r)
            dissipation += 0.5 * value(f"{body.name}.damping.translational", body.damping.translational) * ca.dot(
                b.r_dot, b.r_dot)
            dissipation += 0.25 * value(f"{body.name}.damping.rotational", body.damping.rotational) * sum(
                ca.dot(e, e) for e in b.axes_dot)
        fixed_lengths = {}
        for cable in spec.cables:
            if cable.winch is not None:
                i = self.layout.winch_index[cable.name]
                inertia = value(f"{cable.name}.winch.reflected_inertia", cable.winch.reflected_inertia)
                kinetic += 0.5 * inertia * qd[i] ** 2
            else:
                fixed_lengths[cable.name] = value(f"{cable.name}.length", cable.length)
        return kinetic, potential, dissipation, fixed_lengths

    def geometric_constraints(self, fixed_lengths: dict) -> ca.SX:
        """φ: each body's axes orthonormal (and w = u × v where the spec asks for the redundant rows), each
        cable |d|² − L² (L a winch's coordinate, or the fixed length)."""
        q, phi_rows = self.inputs[0], []
        for body in self.spec.bodies:
            u, v, w = self.bodies[body.name].axes
            phi_rows += [ca.dot(u, u) - 1, ca.dot(v, v) - 1, ca.dot(w, w) - 1, ca.dot(u, v), ca.dot(v, w),
                         ca.dot(w, u)]
            if body.redundant_constraints:
                cross = w - ca.cross(u, v)
                phi_rows += [cross[0], cross[1], cross[2]]
        for cable in self.spec.cables:
            d = self.world_point(cable.ends[0]) - self.world_point(cable.ends[1])
            length = q[self.layout.winch_index[cable.name]] if cable.winch is not None else fixed_lengths[cable.name]
            phi_rows.append(ca.dot(d, d) - length**2)
        return ca.vertcat(*phi_rows)

    def servo_constraints(self) -> ca.SX:
        """σ, the task: the tracked point on the path, an axis at the path's yaw, an axis level."""
        s, p, sigma_rows = self.inputs[2], self.layout.path_signal, []
        for task in self.spec.task:
            b = self.bodies[task.body]
            if isinstance(task, PositionTask):
                sigma_rows.append(b.point(task.point) - s[p : p + 3])
            elif isinstance(task, YawTask):
                axis = b.axes[AXIS_INDEX[task.axis]]
                heading = s[p + 3] + AXIS_HEADING[task.axis]
                sigma_rows.append(-ca.sin(heading) * axis[0] + ca.cos(heading) * axis[1])
            elif isinstance(task, LevelTask):
                axis = b.axes[AXIS_INDEX[task.axis]]
                sigma_rows += [axis[0], axis[1]]
        return ca.vertcat(*sigma_rows)

    def input_matrix(self) -> ca.SX:
        """H(q): the generalized force of each actuator's unit input, times its gain."""
        columns = []
        for act in self.spec.actuators:
            col = ca.SX.zeros(self.layout.n)
            if isinstance(act, WinchTension):
                col[self.layout.winch_index[act.cable]] = -1  # tension > 0 pulls the cable in
            elif isinstance(act, BodyTorque):
                b, i = self.bodies[act.body], self.layout.body_offset[act.body]
                torque = b.axes[AXIS_INDEX[act.axis]]  # unit torque about the body axis
                for k, e in enumerate(b.axes):  # virtual work n . delta_theta
                    col[i + 3 + 3 * k : i + 6 + 3 * k] = 0.5 * ca.cross(torque, e)
            elif isinstance(act, BodyThrust):
                b, i = self.bodies[act.body], self.layout.body_offset[act.body]
                force = b.axes[AXIS_INDEX[act.axis]]
                weights = [1.0, *act.point]  # C(xi)^T f
                for k in range(4):
                    if weights[k] != 0:
                        col[i + 3 * k : i + 3 * k + 3] = weights[k] * force
            columns.append(act.gain * col if act.gain != 1.0 else col)
        return ca.horzcat(*columns)


def _is_zero(entry) -> bool:
    return entry.is_zero() if isinstance(entry, ca.SX) else entry == 0


def _axes_inertia(body, value) -> list[list]:
    """J = ½ tr(I_G) E − I_G with I_G's entries the body's parameters (SX; the products of inertia
    that are zero in the spec stay exact zeros, acroboter.model.physical)."""
    inertia = [[ca.SX(0)] * 3 for _ in range(3)]
    for key, (a, c) in INERTIA_ENTRIES.items():
        if a == c or body.inertia[a][c] != 0.0:
            inertia[a][c] = inertia[c][a] = value(f"{body.name}.inertia.{key}", body.inertia[a][c])
    trace = inertia[0][0] + inertia[1][1] + inertia[2][2]
    return [[0.5 * trace - inertia[a][c] if a == c else -inertia[a][c] for c in range(3)] for a in range(3)]
