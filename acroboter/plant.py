"""The plant: forward dynamics as an index-1 DAE with Baumgarte stabilisation (design §9), with
cables that only pull.

    [M  φ_qᵀ] [q̈]   [H u − c                ]
    [φ_q  0 ] [λ] = [−γ − 2ζ_B ω_B φ̇ − ω_B² φ]      over the rigid rows and the TAUT cables

integrated with fixed-step RK4 for a held input u. The whole RK4 step is one generated C function
(codegen.plant.plant_step_function), written independently of the controllers: it shares only the
symbolic model. Alongside q and q̇ it integrates the work of the inputs, the work of the moving
anchors through the constraint forces (λᵀφ_t) and the energy dissipated by damping. State
x = [q, q̇, W_u, W_anchor, E_d].

Cables (unilateral constraints). A cable only limits the distance of its ends, |p_a − p_b| ≤ L
(L fixed, or the winch's length coordinate); its tension 2Lλ is ≥ 0. The plant keeps an activity
mask `cable_active` (1 taut, 0 slack; all taut at the start) that the generated step takes as an
input (a slack cable's row drops out of the multiplier system, its λ is exactly 0). Per RK4 substep:

- Taut → slack: the step reports each cable's tension at the START of the step. If a taut cable's
  is below −tension_tol (TENSION_TOL_REL × the bodies' total weight, so ~1.8e-7 N on the default
  crane: far below any physical tension, above round-off), it is marked slack and the substep is
  redone from the same state (the most compressed cable first, until no taut cable pushes). This is
  a switch of the active set, not an event inside the step: with u held piecewise constant the
  tension changes smoothly, so the switch is located at step granularity (it happens up to one
  substep late, while the cable pushes by at most about |dT/dt|·h).
- Slack → taut: the step reports each cable's gap |p_a − p_b| − L at the END of the step. If a
  slack cable's gap exceeds GAP_TOL (1e-12 m), the crossing is located inside the substep
  (Illinois regula falsi on the gap, each evaluation one RK4 step of a fraction θ of the substep
  with the path's signals at t, t + θh/2, t + θh) to |gap| ≤ GAP_TOL, the state is advanced there
  and an inelastic impact (restitution 0) is applied with the new active set A (the rigid rows,
  the taut cables and the cable(s) at contact): Λ solves (φ_A M⁻¹ φ_Aᵀ) Λ = φ_A q̇⁻ + φ_t,A and
  q̇⁺ = q̇⁻ − M⁻¹ φ_Aᵀ Λ, which leaves φ̇_A = 0. A cable whose impulse comes out compressive is
  left (or made) slack and Λ is recomputed; a slack cable at contact that the result would
  stretch is added (a small active-set loop; it raises SimulationError if it finds no
  consistent set). Then the rest of the substep is integrated with the new mask. The impulse acts
  in no time: q and the integrated works do not jump; the kinetic energy changes by T⁺ − T⁻,
  which is ≤ 0 for fixed anchors (an inelastic collision) and is accumulated in `impact_energy`,
  so that ΔT + ΔU = W_u + W_anchor − E_d + impact_energy holds across the transitions.
Why: an inextensible cable that goes taut stops the relative motion along it at once; resolving
that as an impulse at the located instant keeps the constraint exact (no stiff spring, no
penetration) and the integration between events is the unchanged smooth RK4.

Limits: slack onset at step granularity (above); re-tension located to ~1e-12 m in gap, but a
gap that goes positive and back within one substep is not seen; every switch costs a redone step,
a located impact a few extra steps (events are rare, the step without one only compares the two
numbers `cable_events` of the generated call with the tolerances); a cable whose row is dependent
(left out of the plant, codegen.structured.independent_rows) is never switched and reports
tension 0. Stage signals at fractional times come from `path` (a hand-made table is taken to
follow `path` when an event happens).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .path import DesiredPath


class SimulationError(RuntimeError):
    pass


# A taut cable goes slack when its start-of-step tension is below −TENSION_TOL_REL × (total weight).
TENSION_TOL_REL = 1e-9
# A slack cable goes taut when its gap exceeds this (m); the crossing is located to the same tolerance.
GAP_TOL = 1e-12
# A slack cable at contact counts as stretched by an impulse when its gap grows faster than this (m/s).
GAP_RATE_TOL = 1e-10


@dataclass(frozen=True)
class CableEvent:
    t: float  # s
    cable: int  # spec cable index
    kind: str  # "slack" or "taut"
    delta_kinetic: float  # J: T⁺ − T⁻ of the impact (0 for a cable going slack)


class StageTable(np.ndarray):
    """The stage signal table with the time of its first row (`t0`), see Plant.stage_table."""

    t0: float | None = None

    def __array_finalize__(self, obj):
        self.t0 = None  # a view or slice does not start where its parent does


class Plant:
    def __init__(self, model, path: DesiredPath, zeta: float, omega: float):
        self.model, self.path = model, path
        self.zeta, self.omega = zeta, omega
        lay = model.layout
        self.n = lay.n
        self.ns = lay.n_signals
        self.state_size = 2 * self.n + 3
        info = model.manifest["functions"]["plant_step"]
        names = [name for name, _ in info["inputs"]]
        # A binding of its own: its outputs and its mask input are this plant's, not shared.
        self._step = model.bind("plant_step")
        self._stage_input = names.index("stage_signals")
        self._x, self._u = model.buffers["x"], model.buffers["u"]
        self._settings = model.buffers["settings"]
        self._stage = model.buffers["stage_signals"]
        self._energy = model.functions["energy"]
        self.cable_names = [c.name for c in model.spec.cables]
        nc = len(self.cable_names)
        self._active = np.ones(nc)
        self._step.point_input(names.index("cable_active"), self._active.ctypes.data)
        out = self._step.outputs
        self._x_next, self._tension, self._gap, self._events = (
            out["x_next"], out["cable_tension"], out["cable_gap"], out["cable_events"])
        rows = list(model.manifest["layout"]["independent_constraint_rows"])
        self._rows = rows
        self._cable_row = [lay.constraints.index(f"cable {name}") for name in self.cable_names]
        self._modelled = [c for c in range(nc) if self._cable_row[c] in rows]
        self._body_rows = [r for r in rows if r not in self._cable_row]
        self._winch = [lay.winch_index.get(c.name) for c in model.spec.cables]
        self._fixed_length = [c.length for c in model.spec.cables]
        weight = sum(b.mass for b in model.spec.bodies) * float(np.linalg.norm(model.spec.gravity))
        self.tension_tol = TENSION_TOL_REL * max(1.0, weight)
        self.gap_tol = GAP_TOL
        self._stage_scratch = np.zeros(9 * self.ns)
        self._minv: np.ndarray | None = None
        self.max_events_per_step = 4 * nc + 4
        # Per run (reset by initial_state):
        self.start_tension = np.zeros(nc)  # tensions at the start of the first substep of the last advance
        self.start_active = np.ones(nc)  # the mask that substep used
        self.impact_energy = 0.0  # J, Σ (T⁺ − T⁻) over the impacts
        self.transitions = np.zeros(nc, dtype=np.int64)
        self.events: list[CableEvent] = []

    # --- state --------------------------------------------------------------------------------
    @property
    def cable_active(self) -> np.ndarray:
        """1.0 taut, 0.0 slack per spec cable (the generated step reads this very array)."""
        return self._active

    @cable_active.setter
    def cable_active(self, value) -> None:
        self._active[:] = value

    def initial_state(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> np.ndarray:
        """x at rest (or at qd0); resets the cables to taut and the event records."""
        x = np.zeros(self.state_size)
        x[: self.n] = q0
        if qd0 is not None:
            x[self.n : 2 * self.n] = qd0
        self._active[:] = 1.0
        self.start_active[:] = 1.0
        self.start_tension[:] = 0.0
        self.impact_energy = 0.0
        self.transitions[:] = 0
        self.events = []
        return x

    def stage_table(self, t0: float, h: float, steps: int) -> StageTable:
        """Signals at t0 + j·h/2 for j = 0..2·steps: RK4 step i reads rows 2i, 2i+1, 2i+2."""
        table = np.ascontiguousarray(self.path.table(t0 + 0.5 * h * np.arange(2 * steps + 1))).view(StageTable)
        table.t0 = float(t0)
        return table

    # --- stepping -----------------------------------------------------------------------------
    def advance(self, x: np.ndarray, u: np.ndarray, h: float, table: np.ndarray, first_step: int,
                steps: int, t0: float | None = None) -> None:
        """`steps` RK4 steps of x (in place) with u held, stage signals from `table`.

        Substep i runs from t0 + i·h; t0 is the table's (stage_table records it), else 0.
        """
        if t0 is None:
            t0 = getattr(table, "t0", None)
            t0 = 0.0 if t0 is None else t0
        self._x[:] = x
        self._u[:] = u
        self._settings[:] = (h, self.zeta, self.omega)
        step, point, stage_input = self._step.call, self._step.point_input, self._stage_input
        out, events, state = self._x_next, self._events, self._x
        tol, gap_tol = self.tension_tol, self.gap_tol
        row_bytes = table.strides[0]
        base = table.ctypes.data
        for i in range(first_step, first_step + steps):
            point(stage_input, base + 2 * i * row_bytes)  # rows 2i..2i+2 are contiguous
            step()
            if events[0] > tol or events[1] > gap_tol:
                self._resolve(t0 + i * h, h, i == first_step)
                continue
            if i == first_step:
                self.start_tension[:] = self._tension
                self.start_active[:] = self._active
            state[:] = out
        point(stage_input, self._stage.ctypes.data)  # never leave a pointer into `table` behind
        x[:] = state

    def step(self, x: np.ndarray, t: float, u: np.ndarray, h: float) -> None:
        """One RK4 step of x (in place) from t to t + h (convenience; evaluates the path here)."""
        self.advance(x, u, h, self.stage_table(t, h, 1), 0, 1)

    def probe(self, x: np.ndarray, u: np.ndarray, t: float) -> None:
        """The cable tensions (start_tension, start_active) at state x and time t with input u, as a
        step from there would see them (taut cables that would push are marked slack); x is kept."""
        self._x[:] = x
        self._u[:] = u
        self._set_stage(t, 0.0)
        self._settings[:] = (0.0, self.zeta, self.omega)
        self._step.call()
        self._release_slack(t)
        self.start_tension[:] = self._tension
        self.start_active[:] = self._active
        self._step.point_input(self._stage_input, self._stage.ctypes.data)

    def mechanical_energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        self.model.q[:] = q
        self.model.qd[:] = qd
        self._energy.call()
        out = self._energy.outputs
        return float(out["kinetic"][0] + out["potential"][0])

    # --- events (rare: numpy and Python are fine here) ------------------------------------------
    def _kinetic(self, q: np.ndarray, qd: np.ndarray) -> float:
        self.model.q[:] = q
        self.model.qd[:] = qd
        self._energy.call()
        return float(self._energy.outputs["kinetic"][0])

    def _note(self, t: float, cable: int, kind: str, delta_kinetic: float = 0.0) -> None:
        self.transitions[cable] += 1
        self.events.append(CableEvent(float(t), cable, kind, float(delta_kinetic)))

    def _set_stage(self, t: float, h: float) -> None:
        """Point the step at the path's signals at t, t + h/2, t + h and set its step to h."""
        self._stage_scratch[:] = self.path.table(np.array([t, t + 0.5 * h, t + h])).reshape(-1)
        self._step.point_input(self._stage_input, self._stage_scratch.ctypes.data)
        self._settings[0] = h

    def _release_slack(self, t: float) -> None:
        """Taut cables that push at the start of the step go slack (most compressed first), and the
        step is redone from the same state, until every taut cable pulls."""
        for _ in range(len(self._modelled)):
            if self._events[0] <= self.tension_tol:
                return
            taut = [c for c in self._modelled if self._active[c] == 1.0]
            c = min(taut, key=lambda k: self._tension[k])
            self._active[c] = 0.0
            self._note(t, c, "slack")
            self._step.call()

    def _resolve(self, t: float, h: float, record: bool) -> None:
        """Finish the substep [t, t + h] from the state in the x buffer, whose step has just been
        called and flagged a cable event; leaves the end state in the x buffer."""
        tau = 0.0  # fraction of the substep done
        refused: set[int] = set()  # cables whose re-tension came out compressive in this substep
        for _ in range(self.max_events_per_step):
            start_t, rest = t + tau * h, (1.0 - tau) * h
            self._release_slack(start_t)
            if record:
                self.start_tension[:] = self._tension
                self.start_active[:] = self._active
                record = False
            candidates = [c for c in self._modelled
                          if self._active[c] == 0.0 and c not in refused and self._gap[c] > self.gap_tol]
            if not candidates:
                self._x[:] = self._x_next
                self._settings[0] = h
                return
            x_start = self._x.copy()
            theta, x_event, gap = self._locate(x_start, start_t, rest, candidates)
            t_event = start_t + theta * rest
            contact = [c for c in self._modelled if self._active[c] == 0.0 and c not in refused
                       and gap[c] >= -self.gap_tol]
            if not contact:
                contact = [max(candidates, key=lambda k: gap[k])]
            refused |= self._impact(x_event, t_event, contact, gap, h)
            tau += theta * (1.0 - tau)
            self._x[:] = x_event
            if 1.0 - tau <= 1e-12:  # the crossing was at the end of the substep
                self._settings[0] = h
                return
            self._set_stage(t + tau * h, (1.0 - tau) * h)
            self._step.call()
        raise SimulationError(
            f"more than {self.max_events_per_step} cable events in the plant step at t = {t:.6f} s "
            "(chattering cables): shorten simulation.step"
        )

    def _gaps_after(self, x_start: np.ndarray, t: float, h: float) -> np.ndarray:
        """The cable gaps after an RK4 step of length h from x_start at t (x buffer: x_start)."""
        self._x[:] = x_start
        self._set_stage(t, h)
        self._step.call()
        return self._gap

    def _locate(self, x_start, t: float, h: float, candidates: list[int]):
        """First θ in [0, 1] where a candidate's gap reaches 0 (to GAP_TOL), the state there and
        every cable's gap there."""
        gap_tol = self.gap_tol

        def g(theta: float) -> float:
            return float(self._gaps_after(x_start, t, theta * h)[candidates].max())

        g_lo = g(0.0)
        if g_lo >= -gap_tol:  # already at contact when the (partial) step starts
            return 0.0, x_start.copy(), self._gap.copy()
        lo, hi = 0.0, 1.0
        g_hi = g(1.0)
        side = 0
        theta = 1.0
        for _ in range(200):
            theta = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
            if not lo < theta < hi:
                theta = 0.5 * (lo + hi)
            value = g(theta)
            if abs(value) <= gap_tol or hi - lo <= 1e-15:
                break
            if value < 0.0:
                lo, g_lo = theta, value
                if side == -1:
                    g_hi *= 0.5  # Illinois: keep the stale end from stalling the secant
                side = -1
            else:
                hi, g_hi = theta, value
                if side == 1:
                    g_lo *= 0.5
                side = 1
        return theta, self._x_next.copy(), self._gap.copy()

    def _inverse_mass(self) -> np.ndarray:
        if self._minv is None:  # natural coordinates: M is constant
            mass = self.model.evaluate("mass_matrix", q=self._x[: self.n])["mass_matrix"]
            self._minv = np.linalg.inv(mass)
        return self._minv

    def _impact(self, x: np.ndarray, t: float, contact: list[int], gap: np.ndarray, h: float) -> set[int]:
        """Inelastic impact at state x (q̇ updated in place) when the `contact` cables come taut.
        Returns the contact cables left slack because their impulse would push."""
        n = self.n
        q, qd = x[:n], x[n : 2 * n].copy()
        s = self.path.table(np.array([t]))[0]
        ns = self.ns
        sig = dict(s=s[:ns], sd=s[ns : 2 * ns], sdd=s[2 * ns :])
        minv = self._inverse_mass()
        phi_q = self.model.evaluate("phi_q", q=q, qd=qd, **sig)["phi_q"]
        phi_dot = self.model.evaluate("phi_dot", q=q, qd=qd, **sig)["phi_dot"]
        before = {c for c in self._modelled if self._active[c] == 1.0}
        at_contact = {c for c in self._modelled if gap[c] >= -self.gap_tol} | set(contact)
        taut = before | set(contact)
        impulse_tol = self.tension_tol * h
        for _ in range(4 * len(self._modelled) + 4):
            rows = self._body_rows + [self._cable_row[c] for c in sorted(taut)]
            jac = phi_q[rows]
            lam = np.linalg.solve(jac @ minv @ jac.T, phi_dot[rows])
            k0 = len(self._body_rows)
            impulse = {c: 2.0 * self._length(c, q) * lam[k0 + j] for j, c in enumerate(sorted(taut))}
            pushing = min(impulse, key=impulse.get, default=None)
            if pushing is not None and impulse[pushing] < -impulse_tol:
                taut.discard(pushing)
                continue
            dqd = minv @ (jac.T @ lam)
            rates = phi_dot - phi_q @ dqd  # φ̇ after the impulse, every row
            stretching = {c: rates[self._cable_row[c]] / (2.0 * self._length(c, q))
                          for c in at_contact - taut}
            worst = max(stretching, key=stretching.get, default=None)
            if worst is not None and stretching[worst] > GAP_RATE_TOL:
                taut.add(worst)
                continue
            break
        else:
            raise SimulationError(f"no consistent set of taut cables for the impact at t = {t:.6f} s")
        if taut != before:
            kinetic_before = self._kinetic(q, qd)
            qd_after = qd - dqd
            delta = self._kinetic(q, qd_after) - kinetic_before
            x[n : 2 * n] = qd_after
            self.impact_energy += delta
            # the impact's energy change goes with its first newly taut cable
            changed = sorted(taut - before) + sorted(before - taut)
            for j, c in enumerate(changed):
                self._active[c] = 1.0 if c in taut else 0.0
                self._note(t, c, "taut" if c in taut else "slack", delta if j == 0 else 0.0)
        return set(contact) - taut

    def _length(self, cable: int, q: np.ndarray) -> float:
        i = self._winch[cable]
        return float(q[i]) if i is not None else float(self._fixed_length[cable])
