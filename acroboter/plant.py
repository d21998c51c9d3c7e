"""The plant: forward dynamics as an index-1 DAE with Baumgarte stabilisation (design §9).

    [M  φ_qᵀ] [q̈]   [H u − c                ]
    [φ_q  0 ] [λ] = [−γ − 2ζ_B ω_B φ̇ − ω_B² φ]

integrated with fixed-step RK4 for a held input u. The whole RK4 step is one generated C function
(codegen.structured.plant_step_function), written independently of the controllers: it shares
only the symbolic model. Alongside q and q̇ it integrates the work of the inputs, the work of the
moving anchors through the constraint forces (λᵀφ_t) and the energy dissipated by damping, so an
energy balance can be checked to the integrator's accuracy. State x = [q, q̇, W_u, W_anchor, E_d].
"""

from __future__ import annotations

import numpy as np

from .path import DesiredPath


class SimulationError(RuntimeError):
    pass


class Plant:
    def __init__(self, model, path: DesiredPath, zeta: float, omega: float):
        self.model, self.path = model, path
        self.zeta, self.omega = zeta, omega
        self.n = model.layout.n
        self._step = model.functions["plant_step"]
        self._x, self._u = model.buffers["x"], model.buffers["u"]
        self._settings = model.buffers["settings"]
        self._stage = model.buffers["stage_signals"]
        self._energy = model.functions["energy"]
        self.state_size = 2 * self.n + 3

    def initial_state(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> np.ndarray:
        x = np.zeros(self.state_size)
        x[: self.n] = q0
        if qd0 is not None:
            x[self.n : 2 * self.n] = qd0
        return x

    def stage_table(self, t0: float, h: float, steps: int) -> np.ndarray:
        """Signals at t0 + j·h/2 for j = 0..2·steps: RK4 step i reads rows 2i, 2i+1, 2i+2."""
        return np.ascontiguousarray(self.path.table(t0 + 0.5 * h * np.arange(2 * steps + 1)))

    def advance(self, x: np.ndarray, u: np.ndarray, h: float, table: np.ndarray, first_step: int,
                steps: int) -> None:
        """`steps` RK4 steps of x (in place) with u held, stage signals from `table`."""
        self._x[:] = x
        self._u[:] = u
        self._settings[:] = (h, self.zeta, self.omega)
        out = self._step.outputs["x_next"]
        row_bytes = table.strides[0]
        base = table.ctypes.data
        for i in range(first_step, first_step + steps):
            self._step.point_input(3, base + 2 * i * row_bytes)  # rows 2i..2i+2 are contiguous
            self._step.call()
            self._x[:] = out
        self._step.point_input(3, self._stage.ctypes.data)  # never leave a pointer into `table` behind
        x[:] = self._x

    def step(self, x: np.ndarray, t: float, u: np.ndarray, h: float) -> None:
        """One RK4 step of x (in place) from t to t + h (convenience; evaluates the path here)."""
        self.advance(x, u, h, self.stage_table(t, h, 1), 0, 1)

    def mechanical_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        self.model.q[:] = q
        self.model.qd[:] = qd
        self._energy.call()
        out = self._energy.outputs
        return float(out["kinetic"][0] + out["potential"][0])
