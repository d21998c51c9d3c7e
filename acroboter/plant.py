"""The plant: forward dynamics as an index-1 DAE with Baumgarte stabilisation (design §9).

    [M  φ_qᵀ] [q̈]   [H u − c                ]
    [φ_q  0 ] [λ] = [−γ − 2ζ_B ω_B φ̇ − ω_B² φ]

integrated with fixed-step RK4 for a held input u. Written independently of the controllers: it
shares only the compiled model terms. Optionally it integrates the power of the inputs, of the
moving anchors (through the constraint forces) and of damping alongside the state, so that an
energy balance can be checked to the integrator's accuracy.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from .compiled import CompiledModel
from .path import DesiredPath


class SimulationError(RuntimeError):
    pass


class Plant:
    def __init__(self, model: CompiledModel, path: DesiredPath, zeta: float, omega: float):
        self.model, self.path = model, path
        self.zeta, self.omega = zeta, omega
        lay = model.layout
        self.n, self.m = lay.n, lay.m
        self._terms = model.functions["model_terms"]
        self._energy = model.functions["energy"]
        size = self.n + self.m
        self._kkt = np.zeros((size, size), order="F")
        self._rhs = np.zeros(size)
        self._gesv = lapack.get_lapack_funcs("gesv", (self._kkt,))
        self.lam = np.zeros(self.m)
        # RK4 work arrays: state x = [q, q̇, W_inputs, W_anchors, E_damping]
        self._k = [np.zeros(2 * self.n + 3) for _ in range(4)]
        self._x = np.zeros(2 * self.n + 3)
        self._stage = np.zeros(2 * self.n + 3)

    def derivative(self, x: np.ndarray, t: float, u: np.ndarray, out: np.ndarray, powers: bool) -> None:
        """out = ẋ for x = [q, q̇, (energy integrals)]."""
        n, m, model = self.n, self.m, self.model
        q, qd = x[:n], x[n : 2 * n]
        model.q[:] = q
        model.qd[:] = qd
        self.path.signals(t, model.s, model.sd, model.sdd)
        self._terms.call()
        T = self._terms.outputs
        K = self._kkt
        K[:n, :n] = T["mass_matrix"]
        K[:n, n:] = T["phi_q"].T
        K[n:, :n] = T["phi_q"]
        K[n:, n:] = 0.0
        np.matmul(T["input_matrix"], u, out=self._rhs[:n])
        self._rhs[:n] -= T["bias_forces"]
        w = self.omega
        self._rhs[n:] = -(T["gamma"] + 2.0 * self.zeta * w * T["phi_dot"] + w * w * T["phi"])
        lu, piv, sol, info = self._gesv(K, self._rhs, overwrite_a=True, overwrite_b=False)
        if info != 0:
            raise SimulationError(
                "the plant's constraint matrix is singular: the spec's geometric constraints are redundant or "
                "degenerate at this state; the forward simulation needs independent constraints"
            )
        out[:n] = qd
        out[n : 2 * n] = sol[:n]
        self.lam[:] = sol[n:]
        if powers:
            phi_q_qd = T["phi_q"] @ qd
            out[2 * n] = u @ (T["input_matrix"].T @ qd)  # inputs
            out[2 * n + 1] = self.lam @ (T["phi_dot"] - phi_q_qd)  # moving anchors: λᵀ φ_t
            self._energy.call()
            out[2 * n + 2] = self._energy.outputs["dissipated_power"][0]  # damping
        else:
            out[2 * n :] = 0.0

    def step(self, x: np.ndarray, t: float, u: np.ndarray, h: float, powers: bool = False) -> None:
        """One RK4 step of x (in place) from t to t + h with u held."""
        k1, k2, k3, k4 = (k[: x.size] for k in self._k)
        stage = self._stage[: x.size]
        self.derivative(x, t, u, k1, powers)
        np.multiply(k1, 0.5 * h, out=stage)
        stage += x
        self.derivative(stage, t + 0.5 * h, u, k2, powers)
        np.multiply(k2, 0.5 * h, out=stage)
        stage += x
        self.derivative(stage, t + 0.5 * h, u, k3, powers)
        np.multiply(k3, h, out=stage)
        stage += x
        self.derivative(stage, t + h, u, k4, powers)
        k2 += k3
        k2 *= 2.0
        k1 += k2
        k1 += k4
        k1 *= h / 6.0
        x += k1

    def mechanical_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        self.model.q[:] = q
        self.model.qd[:] = qd
        self._energy.call()
        out = self._energy.outputs
        return float(out["kinetic"][0] + out["potential"][0])
