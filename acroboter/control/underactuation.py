"""Saturation as underactuation (Zelei, Bencsik, Stépán, J. Comput. Nonlinear Dynam. 12(3), 2017).

The other way to meet a limit than the bounded least squares (acroboter.control.distribution): an input the
task would drive past its limit is held *at* the limit and leaves the unknowns; the servo-constraint inverse
dynamics is solved with the inputs left, and the task components that they cannot serve any more are
released, in the order of a priority the spec states (`[controller.underactuation] priority`, most
important first; docs/saturation.md). When the full task's input is back within its limits, and stays there
for a dwell time, the full task returns.

Every controller's step is written in the servo-constraint accelerations (MLM's constrained dynamics,
generated `mlm_bounded_terms`): σ̈ + 2k_D σ̇ + k_P² σ = E u − e with E = σ_q P H, so that E u = e is the
tracking law on every row. The method's own unbounded input u* asks a = E u* (MLM: a = e; the penalty
methods: the servo accelerations their recovery's input causes). With the inputs split into held H (at
their limits) and free F, the reduced problem is E_F u_F = a − E_H u_H on the kept rows. It is solved by
priority, with an orthonormal basis N of the freedom left (N = I over F at first):

    for each component c, most important first:  J = E_{c,F} N  (its SVD)
        the directions of J with a singular value above UNDERACTUATION_RANK_TOLERANCE × the largest of E_c
        (what all inputs together can do) are met exactly (least squares on them, minimum norm);
        the rest of c is released; N ← N · null(J)
    what is still free (internal forces): toward the preferred values, u_F += N Nᵀ (u_pref − u_F)

A component is *kept* when the free inputs still reach every direction of it that all inputs reach (rank
of J equals the rank of E_c); then σ̈ = −2k_D σ̇ − k_P² σ holds on its rows (for MLM; for the penalty
methods their own ask). A free input that comes out beyond a limit joins the held ones (the one furthest
beyond, relative to its limit's size), and the step is solved again: at most l solves, each a few SVDs of
at most 3 × 7, only while saturated.

The hysteresis (no chatter): the reduced task starts at the first step whose full-task input u* leaves
the limits, and ends only after u* has been inside every limit by `margin` × |limit| for `dwell` seconds
without a break. While it lasts, an input u* drives past a limit joins the held ones; held inputs stay held.
"""

from __future__ import annotations

import numpy as np

from ..model.settings import RANK_TOLERANCE, UNDERACTUATION_RANK_TOLERANCE

DWELL_ROUNDING = 1e-9  # s: control instants k·T in floating point land a rounding off the dwell's multiple


class Underactuation:
    """The held inputs, the released components and the hysteresis of one controller (state kept between steps).

    `components`: task component -> its servo-constraint rows (acroboter.model.spec_checks.task_components);
    `priority`: the components, most important first."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray, preferred: np.ndarray,
                 components: dict[str, list[int]], priority: tuple[str, ...], dwell: float, margin: float):
        self.lower = np.asarray(lower, dtype=float).copy()
        self.upper = np.asarray(upper, dtype=float).copy()
        self.preferred = np.asarray(preferred, dtype=float).copy()
        missing = [c for c in components if c not in priority]
        if missing or any(c not in components for c in priority):
            raise ValueError(f"saturation priority {list(priority)} does not name each task component once "
                             f"({', '.join(components)})")
        self.groups = [(name, np.asarray(components[name], dtype=int)) for name in priority]
        self.dwell, self.margin = float(dwell), float(margin)
        l = self.lower.size
        # Inside each limit by margin × |limit| (a band that is 0 on a limit at 0: there the dwell alone counts).
        with np.errstate(invalid="ignore"):  # an open side (±inf) stays open
            self._inner_lower = np.where(np.isfinite(self.lower), self.lower + self.margin * np.abs(self.lower),
                                         self.lower)
            self._inner_upper = np.where(np.isfinite(self.upper), self.upper - self.margin * np.abs(self.upper),
                                         self.upper)
        self.held = np.zeros(l, dtype=np.int8)  # −1 held at the lower limit, +1 at the upper, 0 free
        self.active = False  # the reduced task is on
        self.released: tuple[str, ...] = ()  # the components the last reduced step released
        self.switches = 0  # reduced ↔ full transitions since the last reset (a chatter count)
        self.solves = 0  # reduced solves of the last step (1 .. l + 1)
        self._inside_since: float | None = None
        self._t_last: float | None = None
        self.u = np.zeros(l)

    def reset(self) -> None:
        """The full task, nothing held (a new run)."""
        self.held[:] = 0
        self.active = False
        self.released = ()
        self.switches = 0
        self._inside_since = self._t_last = None

    def full_task(self, u_star: np.ndarray, t: float) -> bool:
        """Decide the step at time t from the full task's input u*: True, fly the full task (u* as it is);
        False, the reduced task (then call solve). The hysteresis lives here."""
        if self._t_last is not None and t < self._t_last:
            self.reset()  # an earlier time starts a new run
        self._t_last = t
        outside_upper, outside_lower = u_star > self.upper, u_star < self.lower
        if not self.active:
            if not (outside_upper.any() or outside_lower.any()):
                return True
            self.active = True
            self.switches += 1
            self.held[:] = 0
            self._inside_since = None
        else:
            inside = not (np.less(u_star, self._inner_lower).any() or np.greater(u_star, self._inner_upper).any())
            if not inside:
                self._inside_since = None
            elif self._inside_since is None:
                self._inside_since = t
            if inside and t - self._inside_since >= self.dwell - DWELL_ROUNDING:
                self.active = False
                self.switches += 1
                self.held[:] = 0
                self.released = ()
                return True
        # What the full task drives past a limit is held there (at the limit it crosses now).
        self.held[outside_upper] = 1
        self.held[outside_lower] = -1
        return False

    def solve(self, servo_map: np.ndarray, asked: np.ndarray) -> np.ndarray:
        """The reduced step's input: held inputs at their limits, the others by priority (module docstring).
        Grows `held` while a free input comes out beyond a limit; every input ends within its limits."""
        E, l = servo_map, self.lower.size
        if not (np.isfinite(E).all() and np.isfinite(asked).all()):
            raise FloatingPointError("the servo-constraint terms are not finite")
        u = self.u
        self.solves = 0
        for _ in range(l + 1):
            self.solves += 1
            held = self.held != 0
            free = ~held
            u[:] = np.where(self.held > 0, self.upper, self.lower)
            rest = asked - E[:, held] @ u[held] if held.any() else asked.copy()
            x, released = self._prioritised(E, free, rest)
            u[free] = x
            below = np.where(free, self.lower - u, 0.0)
            above = np.where(free, u - self.upper, 0.0)
            worst = np.maximum(below, above)
            if not (worst > 0).any():
                break
            size = np.maximum(np.abs(np.where(above > below, self.upper, self.lower)), 1.0)
            with np.errstate(invalid="ignore"):  # an open side: −inf − u, never beyond (masked)
                i = int(np.argmax(np.where(worst > 0, worst / size, -np.inf)))
            self.held[i] = 1 if above[i] > below[i] else -1
        else:  # unreachable: each round holds one more input, and with all held nothing is free
            raise RuntimeError("the underactuation's active set did not settle")
        self.released = released
        return u

    def _prioritised(self, E: np.ndarray, free: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
        """u_F meeting the components by priority with the free inputs, and the components released."""
        EF = E[:, free]
        nf = EF.shape[1]
        x = np.zeros(nf)
        basis = np.eye(nf)  # orthonormal: the freedom left
        released = []
        for name, rows in self.groups:
            Ec = E[rows]
            full = np.linalg.svd(Ec, compute_uv=False)
            scale = float(full[0]) if full.size else 0.0
            reach = int(np.count_nonzero(full > RANK_TOLERANCE * scale)) if scale > 0 else 0
            if basis.shape[1] == 0:
                rank = 0
            else:
                J = EF[rows] @ basis
                U, s, Vt = np.linalg.svd(J, full_matrices=True)
                rank = int(np.count_nonzero(s > UNDERACTUATION_RANK_TOLERANCE * scale)) if scale > 0 else 0
                if rank:
                    miss = rest[rows] - EF[rows] @ x
                    x += basis @ (Vt[:rank].T @ ((U[:, :rank].T @ miss) / s[:rank]))
                basis = basis @ Vt[rank:].T
            if rank < reach:
                released.append(name)
        if basis.shape[1]:
            x += basis @ (basis.T @ (self.preferred[free] - x))
        return x, tuple(released)
