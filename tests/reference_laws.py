"""Reference laws for the tests, in 40-digit arithmetic (mpmath) from the model's terms: a reference free of the
round-off of any formulation the package uses (tests/test_export_step.py, tests/test_fast_path.py)."""

from __future__ import annotations

import mpmath
import numpy as np


def penalty_inputs_40_digits(model, desired, gains, method, states) -> np.ndarray:
    """The penalty methods with the projected recovery (the fit of the servo accelerations, E u + σ_q P σ_qᵀλ̂ = 0,
    least squares where there are more servo-constraints than inputs), in 40-digit
    arithmetic (mpmath), from the model terms at each state: a reference free of the round-off of either
    formulation. With more inputs than
    servo-constraints, the distribution of the same fit, lexicographic in the servo accelerations
    (acroboter.control.distribution.BoundedInputs.solve_task), which must be within the limits at these states (the
    reference has no QP)."""
    iterations = 1 if method == "penalty" else int(method.removeprefix("iterative-"))
    lay = model.layout
    lower, upper, preferred = model.spec.input_limits()
    rows = [i for i in range(lay.m) if i not in lay.redundant_rows]
    out = []
    with mpmath.workdps(40):
        for t, q, qd in states:
            s, sd, sdd = desired.signal_arrays(t)
            T = {name: mpmath.matrix(np.atleast_1d(model.term(name, q, qd, s, sd, sdd)).tolist()) for name in (
                "mass_matrix", "bias_forces", "phi", "phi_q", "phi_dot", "gamma",
                "sigma", "sigma_q", "sigma_dot", "gamma_s", "input_matrix",
            )}
            M, phi_q, sigma_q, H = T["mass_matrix"], T["phi_q"], T["sigma_q"], T["input_matrix"]
            rho = T["gamma"] + 2 * gains.omega * gains.mu * T["phi_dot"] + gains.omega**2 * T["phi"]
            rho_s = T["gamma_s"] + 2 * gains.kd * T["sigma_dot"] + gains.kp**2 * T["sigma"]
            A = M + gains.alpha_geometric * phi_q.T * phi_q + gains.alpha_servo * sigma_q.T * sigma_q
            force = -gains.alpha_geometric * phi_q.T * rho - gains.alpha_servo * sigma_q.T * rho_s
            qdd = mpmath.lu_solve(A, force - T["bias_forces"])
            total = qdd
            for _ in range(iterations - 1):
                qdd = mpmath.lu_solve(A, M * qdd + force)
                total += qdd
            lam_hat = gains.alpha_servo * (sigma_q * total + iterations * rho_s)
            # P = M⁻¹ − M⁻¹φ_qᵀ(φ_q M⁻¹φ_qᵀ)⁻¹φ_q M⁻¹ over the kept rows: the acceleration a force causes
            minv = M**-1
            phi = mpmath.matrix([[phi_q[row, c] for c in range(lay.n)] for row in rows])
            P = minv - minv * phi.T * mpmath.inverse(phi * minv * phi.T) * phi * minv
            E = sigma_q * P * H
            G, g = E.T * E, E.T * (sigma_q * P * sigma_q.T) * lam_hat  # the servo accelerations: |E u + F λ̂|²
            G = (G + G.T) / 2
            if lay.l > lay.k:
                # lexicographic in the servo accelerations (BoundedInputs.solve_task):
                # u_F = −Eᵀ(E G Eᵀ)⁻¹E g, then u = u_F + (I − Eᵀ(EEᵀ)⁻¹E)(u_pref − u_F)
                u_task = -(E.T * mpmath.lu_solve(E * G * E.T, E * g))
                shift = mpmath.matrix(preferred.tolist()) - u_task
                x = u_task + shift - E.T * mpmath.lu_solve(E * E.T, E * shift)
                u = np.array([float(x[j]) for j in range(lay.l)])
                assert np.all(u >= lower) and np.all(u <= upper), "the reference needs u within the limits"
                out.append(u)
                continue
            x = mpmath.lu_solve(G, -g)
            out.append([float(x[j]) for j in range(lay.l)])
    return np.array(out)
