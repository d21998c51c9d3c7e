"""The plant's cable events: what happens when a cable goes slack or snaps taut (acroboter.sim.plant).

Cables (unilateral constraints). A cable only limits the distance of its ends, |p_a − p_b| ≤ L
(L fixed, or the winch's length coordinate); its tension 2Lλ is ≥ 0. The plant keeps an activity
mask `cable_active` (1 taut, 0 slack; all taut at the start) that the generated step takes as an
input (a slack cable's row drops out of the multiplier system, its λ is exactly 0). The step
reports each cable's tension at its START and gap |p_a − p_b| − L at its END, and two numbers
(`cable_events`) that say whether a taut cable pushes (tension < −tension_tol, TENSION_TOL_REL ×
the bodies' weight, ~1.8e-7 N on the default crane: far below any physical tension, above
round-off) or a slack one ends stretched (gap > GAP_TOL = 1e-12 m). A substep without either costs
two float comparisons. Otherwise (rare; numpy):

- Force level, at the start of the (partial) step: over the cables at contact with no relative
  velocity (the taut ones, and slack ones at contact that neither stretch nor separate), the mask is
  the solution of the complementarity conditions of the plant's own stabilised multiplier system
  at that instant: taut cables pull, slack ones are not accelerated into stretch. The system is
  positive definite, so the solution is unique; it is found among all masks of those cables
  (nearest to the current first). A slack cable separating so slowly, under an acceleration back into stretch, that its
  dip would be shallower than GAP_TOL (too shallow to locate its return) is taken taut there too,
  with its tiny rate projected out (the energy that return's impact would take, into impact_energy).
- Taut → slack inside the step: a taut cable whose tension crosses zero inside the step (the step
  flags it from its last RK4 stage's estimate of the end tension; one it misses near the step's end goes
  slack at the next step's start) has the instant located by Illinois
  regula falsi on its exact tension at the end of a partial step (acroboter.sim.cable_crossings), to
  within [−tension_tol, 0]; it goes slack there and the rest of the step runs without it. (It went slack
  at the start of the next step before, having pushed for up to a step: 52 mm off MuJoCo on a generated
  crane, docs/plant-fuzz-cranes.md.)
- Slack → taut inside the step: a slack cable that ends the step stretched has its crossing located
  by Illinois regula falsi (each evaluation one RK4 step of a fraction θ of the step with the path's
  signals at t, t + θh/2, t + θh) to |gap| ≤ GAP_TOL: on the gap g(θ) when the cable starts below
  contact, on the secant slope (g(θ) − g(0))/θ when it starts at contact and separates first (that
  slope starts at the separation rate and ends positive, so the return is bracketed however shallow
  and short the dip: the scan for a point below −GAP_TOL that preceded it missed dips of a few
  picometres and microseconds, and the cable ended the step stretched, issue 18). The state is
  advanced there and an inelastic impact (restitution 0) is applied with the new active set A (the
  rigid rows, the taut cables and the cable(s) at contact): Λ solves
  (φ_A M⁻¹ φ_Aᵀ) Λ = φ_A q̇⁻ + φ_t,A and q̇⁺ = q̇⁻ − M⁻¹ φ_Aᵀ Λ, which leaves φ̇_A = 0. A with every
  taut cable's impulse pulling and no slack cable at contact left being stretched is found among
  all sets of the cables at contact (velocity-level complementarity): a cable whose impulse would
  push is left (or made) slack and separates. Then the rest of the step runs with the new mask
  (force level first again). Cascades (a cable pulled taut throws another one slack, which comes
  back microseconds later) are followed event by event, up to max_events_per_step.
- Energy: the impulse acts in no time (q and the integrated works do not jump); the kinetic energy
  changes by T⁺ − T⁻, ≤ 0 for fixed anchors (an inelastic collision), accumulated in
  `impact_energy`, so that ΔT + ΔU = W_u + W_anchor − E_d + impact_energy holds across the
  transitions to the integrator's accuracy (tests/test_unilateral.py, tests/test_plant_fuzz.py).
- Invariants, checked in every run (InvariantError, a SimulationError naming the time, the cable and
  the figures; a run reports it as a divergence): after every substep with an event, no slack cable
  is stretched beyond STRETCH_TOL and no taut cable pushes beyond PUSH_TOL_REL × the weight (a
  substep without an event meets both by the two comparisons above); at the end of every advance
  (each control period) and after every substep with an event, |energy balance residual| ≤
  ENERGY_TOL_REL × (weight × longest cable + peak kinetic energy). `cable_gap` and
  `energy_residual` hold the last figures (the run's records and CSV carry them).
Why: an inextensible cable that goes taut stops the relative motion along it at once; resolving
that as an impulse at the located instant keeps the constraint exact (no stiff spring, no
penetration) and the integration between events is the unchanged smooth RK4.

Limits: a tension that dips below zero and back within one substep is not seen; re-tension located to
~1e-12 m in gap; a gap that goes positive and back within one substep is not seen; a cable whose row is dependent
(left out of the plant, acroboter.codegen.solver_terms.independent_rows) is never switched and reports
tension 0. Stage signals at fractional times come from `path` (a hand-made table is taken to follow
`path` when an event happens). No consistent state within max_events_per_step events raises
SimulationError (simulate reports it as a divergence).

The methods here are the event half of acroboter.sim.plant.Plant (a mixin: they read its bindings,
buffers and mask); they run only in the substeps the generated step flags, so numpy and Python are
fine here. Why a module of its own: the event logic is one thing, read apart from the stepping.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .cable_crossings import CableCrossings


class SimulationError(RuntimeError):
    """The plant cannot go on: no consistent cable state, a broken invariant, a state that turned
    non-finite. A run reports it as a divergence (its time, exit 3 from the command line)."""


class InvariantError(SimulationError):
    """A physical invariant of the plant broke (a slack cable stretched, a taut one pushing, energy
    created or lost without a cause): the message names the time, the cable and the figures."""


# A taut cable goes slack when its start-of-step tension is below −TENSION_TOL_REL × (total weight).
TENSION_TOL_REL = 1e-9
# A slack cable goes taut when its gap exceeds this (m); the crossing is located to the same tolerance.
GAP_TOL = 1e-12
# A cable whose ends start closer than its length by more than this (m) starts slack (Plant.initial_state);
# the static start's cables are at their lengths to round-off.
START_SLACK_GAP = 1e-9
# A slack cable at contact counts as stretched by an impulse when its gap grows faster than this (m/s),
# and as accelerated into stretch when its gap's acceleration exceeds GAP_ACC_TOL (m/s²).
GAP_RATE_TOL = 1e-10
GAP_ACC_TOL = 1e-7
# Invariants checked in every run (InvariantError beyond them): no slack cable ends a substep stretched
# by more than STRETCH_TOL (m); no taut cable starts a substep pushing by more than PUSH_TOL_REL × the
# bodies' weight (N); |energy residual| stays within acroboter.sim.plant.ENERGY_TOL_REL × the energy scale (J):
# weight × the longest cable (at the start) + the largest kinetic energy seen so far. Seen: stretch 0,
# push 0 (the resolved steps meet GAP_TOL and TENSION_TOL_REL), residual ≤ 1e-4 J against a bound of
# 2.6e-3 J on the default crane (docs/plant.md).
STRETCH_TOL = 1e-9
PUSH_TOL_REL = 1e-6


@dataclass(frozen=True)
class CableEvent:
    t: float  # s
    cable: int  # spec cable index
    kind: str  # "slack" or "taut"
    delta_kinetic: float  # J: T⁺ − T⁻ of the impact (0 for a cable going slack)


class CableEvents(CableCrossings):
    """The event logic of Plant (see the module docstring); Plant provides the state it works on."""

    def _kinetic(self, q: np.ndarray, qd: np.ndarray) -> float:
        return self._energies(q, qd)[0]

    def _note(self, t: float, cable: int, kind: str, delta_kinetic: float = 0.0) -> None:
        self.transitions[cable] += 1
        self.events.append(CableEvent(float(t), cable, kind, float(delta_kinetic)))

    def _set_stage(self, t: float, h: float) -> None:
        """Point the step at the path's signals at t, t + h/2, t + h and set its step to h."""
        self._stage_scratch[:] = self._path_rows((t, t + 0.5 * h, t + h)).reshape(-1)
        self._step.point_input(self._stage_input, self._stage_scratch.ctypes.data)
        self._settings[0] = h

    def _release_slack(self, t: float) -> None:
        """Taut cables that push at the start of the step go slack (most compressed first), and the
        step is redone from the same state, until every taut cable pulls (used by probe)."""
        for _ in range(len(self._modelled)):
            if self._events[0] <= self.tension_tol:
                return
            taut = [c for c in self._modelled if self._active[c] == 1.0]
            c = min(taut, key=lambda k: self._tension[k])
            self._active[c] = 0.0
            self._note(t, c, "slack")
            self._step.call()

    def _point_step(self, t: float, h: float, address: int | None) -> None:
        """Set the step to [t, t + h]: the table's rows at `address`, else the path's signals."""
        if address is None:
            self._set_stage(t, h)
        else:
            self._step.point_input(self._stage_input, address)
            self._settings[0] = h

    def _resolve(self, t: float, h: float, record: bool, address: int) -> None:
        """Finish the substep [t, t + h] from the state in the x buffer, whose step has just been
        called (stage signals at `address`) and flagged a cable event; leaves the end state in the x
        buffer and the step's settings at h."""
        tau = 0.0  # fraction of the substep done
        refused: set[int] = set()  # cables whose re-tension came out compressive at the current instant
        for _ in range(self.max_events_per_step):
            start_t, rest = t + tau * h, (1.0 - tau) * h
            here = address if tau == 0.0 else None
            self._settle(start_t, rest, here, refused, h)
            if record:
                self.start_tension[:] = self._tension
                self.start_active[:] = self._active
                record = False
            candidates = [c for c in self._modelled if self._active[c] == 0.0 and self._gap[c] > self.gap_tol]
            x_start = self._x.copy()
            # the step, its start settled, still flags a push: a taut cable's tension crosses zero inside it
            pushes = self._events[0] > self.tension_tol
            onset = self._slack_onset(x_start, start_t, rest, here) if pushes else None
            located = self._locate(x_start, start_t, rest, candidates, here) if candidates or pushes else None
            if onset is not None and (located is None or onset[0] < located[0]):
                theta, cable, x_event = onset  # it goes slack there, and the rest of the step runs without it
                if theta > 0.0:
                    refused = set()
                self._active[cable] = 0.0
                self._note(start_t + theta * rest, cable, "slack")
                tau += theta * (1.0 - tau)
                self._x[:] = x_event
                if 1.0 - tau <= 1e-12:  # at the end of the substep: its end state, its gaps there
                    self._gaps_after(x_event, t + h, 0.0)
                    self._end_substep(t, h)
                    return
                continue
            if located is None:  # no slack cable crosses into stretch inside the step
                self._x[:] = self._x_next
                self._end_substep(t, h)
                return
            theta, x_event, gap = located
            t_event = start_t + theta * rest
            if theta > 0.0:
                refused = set()  # a new instant
            contact = [c for c in self._modelled if self._active[c] == 0.0 and c not in refused
                       and gap[c] >= -self.gap_tol]
            if contact:
                refused |= self._impact(x_event, t_event, contact, gap, h)
            tau += theta * (1.0 - tau)
            self._x[:] = x_event
            if 1.0 - tau <= 1e-12:  # the crossing was at the end of the substep
                self._gap[:] = gap  # the end's gaps (the impact moved no position)
                self._end_substep(t, h)
                return
        raise SimulationError(
            f"more than {self.max_events_per_step} cable events in the plant step at t = {t:.6f} s "
            "(chattering cables): shorten simulation.step"
        )

    def _end_substep(self, t: float, h: float) -> None:
        """The substep [t, t + h] resolved, its end state in the x buffer: the step's settings back to h, and the
        invariants checked there."""
        self._settings[0] = h
        self._check_cables(t + h)
        self._check_energy(self._x, t + h)

    def _terms_at(self, x: np.ndarray, t: float) -> dict[str, np.ndarray]:
        n, ns = self.n, self.ns
        s = self._path_rows((t,))[0]
        self.model.set_inputs(q=x[:n], qd=x[n : 2 * n], s=s[:ns], sd=s[ns : 2 * ns], sdd=s[2 * ns :])
        self._terms.call()
        return {k: v.copy() for k, v in self._terms.outputs.items()}

    def _contact_state(self, x: np.ndarray, t: float):
        """The model terms, every cable's gap (m) and gap rate (m/s) at state x and time t."""
        self._x[:] = x
        self._set_stage(t, 0.0)  # a step of length 0: its end gap is the gap at x
        self._step.call()
        gap = self._gap.copy()
        terms = self._terms_at(x, t)
        rate = np.array([self._gap_rate(c, x, terms["phi_dot"][r], gap[c]) for c, r in enumerate(self._cable_row)])
        return terms, gap, rate

    def _gap_rate(self, cable: int, x: np.ndarray, phi_dot: float, gap: float) -> float:
        """d/dt (|d| − L) from φ̇ = 2 (d·ḋ − L L̇): (φ̇/2 + L L̇)/|d| − L̇ with |d| = L + gap."""
        length = self._length(cable, x[: self.n])
        i = self._winch[cable]
        length_rate = float(x[self.n + i]) if i is not None else 0.0
        return (0.5 * phi_dot + length * length_rate) / (length + gap) - length_rate

    def _settle(self, t: float, h: float, address: int | None, refused: set[int], substep: float) -> None:
        """Make the cable mask consistent at the start of the step [t, t + h] from the x buffer and
        leave that step called with it.

        Slack cables at contact (gap ≥ −GAP_TOL) that are being stretched get their impact first.
        Then the cables at contact with no relative velocity (the taut ones and the slack ones at
        contact that neither stretch nor separate) take the force-level complementarity conditions
        of the plant's own multiplier system, solved exactly at this instant: a taut cable pulls
        (2Lλ ≥ −tension_tol), a slack one is not being accelerated into stretch (its row's
        stabilised acceleration (φ_q q̈ + γ + 2ζωφ̇ + ω²φ)/2L ≤ GAP_ACC_TOL: the same equation the
        plant enforces when it is taut). The system is positive definite, so exactly one such set
        exists; it is found among all of them (at most 2^cables small numpy solves, rare), nearest
        (fewest switches) to the current mask first.
        """
        gap_tol = self.gap_tol
        x = self._x.copy()
        terms, gap, rate = self._contact_state(x, t)
        stretching = [c for c in self._modelled if self._active[c] == 0.0 and c not in refused
                      and gap[c] >= -gap_tol and rate[c] > GAP_RATE_TOL]
        if stretching:
            refused |= self._impact(x, t, stretching, gap, substep)
            terms, gap, rate = self._contact_state(x, t)
        self._x[:] = x
        # Slack cables at contact that are not stretched: at rest relative to it, or separating so
        # slowly under an acceleration back into stretch that the dip (ġ²/2g̈) is below GAP_TOL, too
        # shallow to locate a return: both are at contact for the force-level decision.
        taut = [c for c in self._modelled if self._active[c] == 1.0]
        acc = self._row_accelerations(x, terms, taut)[1]
        contact = [c for c in self._modelled if self._active[c] == 1.0 or (
            gap[c] >= -gap_tol and rate[c] <= GAP_RATE_TOL
            and (rate[c] >= -GAP_RATE_TOL or rate[c] ** 2 <= 2.0 * gap_tol * max(acc[c], 0.0)))]
        start = self._active.copy()
        mask = self._force_level(x, terms, contact)
        self._active[:] = mask
        # A cable taken taut while still separating (the shallow dip above) would leave Baumgarte to
        # stop it, with work that no term of the balance holds: its rate is projected out at once
        # instead (what the return would lose in its impact, ≤ 0, into impact_energy).
        delta = 0.0
        if any(mask[c] == 1.0 and start[c] == 0.0 and abs(rate[c]) > GAP_RATE_TOL for c in contact):
            delta = self._project_rates(x, terms, [c for c in self._modelled if mask[c] == 1.0])
            self._x[:] = x
        first = True
        for c in contact:
            if mask[c] != start[c]:
                self._note(t, c, "taut" if mask[c] == 1.0 else "slack", delta if first else 0.0)
                first = False
        self._point_step(t, h, address)
        self._step.call()
        for c in self._modelled:
            if self._active[c] == 1.0 and self._tension[c] < -self.push_tol:
                raise InvariantError(
                    f"at t = {t:.6f} s cable '{self.cable_names[c]}' is taut but pushes with {-self._tension[c]:.3e} N "
                    f"(tolerance {self.push_tol:.2e} N): no taut/slack set of the cables is consistent here")

    def _project_rates(self, x: np.ndarray, terms: dict, taut: list[int]) -> float:
        """q̇ ← q̇ − M⁻¹φ_Aᵀ(φ_A M⁻¹φ_Aᵀ)⁻¹ φ̇_A over the rigid rows and the `taut` cables (x in
        place): φ̇_A = 0 afterwards. Returns (and books in impact_energy) the kinetic energy change."""
        n = self.n
        q, qd = x[:n], x[n : 2 * n].copy()
        minv = self._inverse_mass()
        rows = self._body_rows + [self._cable_row[c] for c in sorted(taut)]
        jac = terms["phi_q"][rows]
        lam = np.linalg.solve(jac @ minv @ jac.T, terms["phi_dot"][rows])
        qd_after = qd - minv @ (jac.T @ lam)
        delta = self._kinetic(q, qd_after) - self._kinetic(q, qd)
        x[n : 2 * n] = qd_after
        self.impact_energy += delta
        return delta

    def _row_accelerations(self, x: np.ndarray, terms: dict, taut: list[int]):
        """With the rigid rows and the `taut` cables enforced (the plant's multiplier system, in
        numpy): every cable's tension 2Lλ (N; 0 for the others) and its row's stabilised
        acceleration (φ_q q̈ + γ + 2ζωφ̇ + ω²φ)/2L (m/s²; ≈ 0 for the taut ones). None if singular."""
        q = x[: self.n]
        minv = self._inverse_mass()
        force = terms["input_matrix"].reshape(self.n, -1, order="F") @ self._u - terms["bias_forces"]
        minv_force = minv @ force
        baumgarte = terms["gamma"] + 2 * self.zeta * self.omega * terms["phi_dot"] + self.omega**2 * terms["phi"]
        taut = sorted(taut)
        rows = self._body_rows + [self._cable_row[c] for c in taut]
        jac = terms["phi_q"][rows]
        try:
            lam = np.linalg.solve(jac @ minv @ jac.T, jac @ minv_force + baumgarte[rows])
        except np.linalg.LinAlgError:
            return None, None
        qdd = minv_force - minv @ (jac.T @ lam)
        lengths = np.array([self._length(c, q) for c in range(len(self._cable_row))])
        tension = np.zeros(len(self._cable_row))
        k0 = len(self._body_rows)
        for j, c in enumerate(taut):
            tension[c] = 2.0 * lengths[c] * lam[k0 + j]
        acc = (terms["phi_q"][self._cable_row] @ qdd + baumgarte[self._cable_row]) / (2.0 * lengths)
        return tension, acc

    def _force_level(self, x: np.ndarray, terms: dict, contact: list[int]) -> np.ndarray:
        """The mask over `contact` that satisfies the force-level conditions (see _settle)."""
        start = self._active.copy()
        fixed_taut = [c for c in self._modelled if start[c] == 1.0 and c not in contact]
        best, best_violation = start, np.inf
        for size in range(len(contact) + 1):
            for flip in combinations(contact, size):
                mask = start.copy()
                for c in flip:
                    mask[c] = 1.0 - start[c]
                tension, acc = self._row_accelerations(x, terms, fixed_taut + [c for c in contact if mask[c] == 1.0])
                if tension is None:
                    continue
                violation = 0.0
                for c in contact:
                    if mask[c] == 1.0:  # pulls
                        violation = max(violation, (-tension[c] - self.tension_tol) / self.tension_tol)
                    else:  # is not accelerated into stretch
                        violation = max(violation, (acc[c] - GAP_ACC_TOL) / GAP_ACC_TOL)
                if violation <= 0.0:
                    return mask
                if violation < best_violation:
                    best, best_violation = mask, violation
        return best  # none within the tolerances (round-off): the least violating

    def _inverse_mass(self) -> np.ndarray:
        if self._minv is None:  # natural coordinates: M is constant
            self.model.q[:] = self._x[: self.n]
            self._terms.call()
            self._minv = np.linalg.inv(self._terms.outputs["mass_matrix"])
        return self._minv

    def _impact(self, x: np.ndarray, t: float, contact: list[int], gap: np.ndarray, h: float) -> set[int]:
        """Inelastic impact at state x (q̇ updated in place) when the `contact` cables come taut.

        The taut set after it is the one nearest (fewest switches) the taut cables plus `contact`
        under which every taut cable's impulse pulls and no slack cable at contact is left being
        stretched (complementarity at velocity level, searched over all sets of the cables at
        contact: at most 2^cables small solves, rare). Returns the contact cables left slack.
        """
        n = self.n
        q, qd = x[:n], x[n : 2 * n].copy()
        terms = self._terms_at(x, t)
        phi_q, phi_dot = terms["phi_q"], terms["phi_dot"]
        minv = self._inverse_mass()
        before = {c for c in self._modelled if self._active[c] == 1.0}
        wanted = before | set(contact)
        at_contact = sorted({c for c in self._modelled if gap[c] >= -self.gap_tol} | wanted)
        impulse_tol = self.tension_tol * h
        lengths = {c: self._length(c, q) for c in at_contact}
        best, best_violation, chosen = None, np.inf, None
        for size in range(len(at_contact) + 1):
            for flip in combinations(at_contact, size):
                taut = wanted ^ set(flip)
                order = sorted(taut)
                rows = self._body_rows + [self._cable_row[c] for c in order]
                jac = phi_q[rows]
                try:
                    lam = np.linalg.solve(jac @ minv @ jac.T, phi_dot[rows])
                except np.linalg.LinAlgError:  # a degenerate set (e.g. a state gone wild): not this one
                    continue
                dqd = minv @ (jac.T @ lam)
                rates = phi_dot - phi_q @ dqd  # φ̇ after the impulse, every row
                k0 = len(self._body_rows)
                violation = 0.0
                for j, c in enumerate(order):  # impulses pull: 2 L Λ ≥ 0
                    violation = max(violation, (-2.0 * lengths[c] * lam[k0 + j] - impulse_tol) / impulse_tol)
                for c in at_contact:  # slack ones are not stretched afterwards
                    if c not in taut:
                        rate = rates[self._cable_row[c]] / (2.0 * lengths[c])
                        violation = max(violation, (rate - GAP_RATE_TOL) / GAP_RATE_TOL)
                if violation <= 0.0:
                    chosen = (taut, dqd)
                    break
                if violation < best_violation:
                    best, best_violation = (taut, dqd), violation
            if chosen is not None:
                break
        if chosen is None and best is None:
            raise SimulationError(f"no taut set of the cables solves the impact at t = {t:.6f} s")
        taut, dqd = chosen if chosen is not None else best  # none within the tolerances: the least violating
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

    def _check_cables(self, t: float) -> None:
        """After a resolved substep: no slack cable is stretched beyond STRETCH_TOL (self._gap is the
        substep's end). (That no taut cable pushes beyond push_tol is checked where the mask is decided,
        at the end of _settle.)"""
        for c in self._modelled:
            if self._active[c] == 0.0 and self._gap[c] > STRETCH_TOL:
                raise InvariantError(
                    f"at t = {t:.6f} s cable '{self.cable_names[c]}' is slack but stretched by {self._gap[c]:.3e} m "
                    f"(tolerance {STRETCH_TOL:g} m): the plant lost a re-tension; report the inputs that led here")
