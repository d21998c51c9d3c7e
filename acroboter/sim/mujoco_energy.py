"""The work of MuJoCo's constraint forces, step by MuJoCo step: what its compliant cable limits take out
of the crane around a re-tension (the own plant's inelastic impact takes T⁺ − T⁻ in no time,
acroboter.sim.cable_events; MuJoCo's limit is a stiff damped spring that takes it over a few steps).

    ledger = ConstraintWork(plant)     # a MujocoPlant; its advance then steps MuJoCo one step at a time
    ... plant.advance(...) ...
    ledger.work                        # J: the constraint forces' work since the start (≤ 0 dissipates)

Formulation: across one MuJoCo step, with the state's energy E = T + U read by MuJoCo (mjENBL_ENERGY:
kinetic ½ q̇ᵀMq̇ with the drums' armature, gravity's potential) at its start and end,

    W_constraint = ΔE − W_actuators − W_damping − W_applied,

everything else that acts on the crane being smooth. The constraint forces (here only the cables'
limits: contacts are off, the model has no equality constraint) act through a re-tension in a few
steps, so their work is not integrated from sampled forces (a trapezoid over a force that rises and
falls within a step misses tens of per cent of it); it is the step's energy balance instead, whose
other terms are smooth or exact:
- actuators: over a slide or hinge joint and a free joint's translation, ½(f₀ + f₁)·Δq (exact for a
  winch, whose force is constant within a step with u held, however fast its drum moves through the
  snap); over rotations (a free or ball joint's angular velocity), ½(f₀·q̇₀ + f₁·q̇₁)·h;
- joint damping: ½(P₀ + P₁)·h, P = qfrc_damper·q̇ (smooth: the bodies' damping is small against the
  impulses);
- applied forces (a moving anchor's acceleration on its armature): as actuators (0 with anchors held).
A moving anchor's slide joints are reset to the path at each step; with anchors held (open loop) the
reset changes E by ~1e-12 J (the cables move an anchor of 1e9 kg armature by ~1e-15 m in a step).
The energy E also holds what MuJoCo's soft cable limits store: a taut limit is a stiff spring in
constraint space (its impedance is constant, 0.9999, so force and stretch r are proportional), whose
energy is ½·f·r (f its force, r = −efc_pos its stretch). Left out, a taut cable whose load changes books
that storage as constraint work (measured: +1.6e-5 J over 8 ms before a snap of acroboter seed 924, the
tensions swinging under a 2 Hz sine; 3e-7 J with it). So over a window around a re-tension W_constraint
is the energy its impact took, compared with the own plant's T⁺ − T⁻ (acroboter.studies.plant_differential)."""

from __future__ import annotations

import numpy as np


class ConstraintWork:
    """The cumulative work of `plant`'s (a MujocoPlant) constraint forces, sampled at every MuJoCo step."""

    def __init__(self, plant):
        mj, m = plant._mj, plant.mj_model
        self._mj, self._m, self._d = mj, m, plant.mj_data
        m.opt.enableflags |= int(mj.mjtEnableBit.mjENBL_ENERGY)
        jt = mj.mjtJoint
        positional_dof, positional_qpos = [], []  # dofs whose work is f·Δq, and their qpos addresses
        for j in range(m.njnt):
            kind, dof, qpos = int(m.jnt_type[j]), int(m.jnt_dofadr[j]), int(m.jnt_qposadr[j])
            if kind in (int(jt.mjJNT_SLIDE), int(jt.mjJNT_HINGE)):
                positional_dof.append(dof), positional_qpos.append(qpos)
            elif kind == int(jt.mjJNT_FREE):
                positional_dof += [dof, dof + 1, dof + 2]
                positional_qpos += [qpos, qpos + 1, qpos + 2]
        self._pos_dof, self._pos_qpos = np.array(positional_dof, dtype=int), np.array(positional_qpos, dtype=int)
        rotational = np.ones(m.nv, dtype=bool)
        rotational[self._pos_dof] = False
        self._rot_dof = np.flatnonzero(rotational)
        self._limit = int(mj.mjtConstraint.mjCNSTR_LIMIT_TENDON)
        self.work = 0.0  # J, since the start (or the last reset)
        self._last: tuple | None = None
        plant.ledger = self

    def reset(self) -> None:
        self.work = 0.0
        self._last = None

    def _sample(self) -> tuple:
        """The figures of the current state (MuJoCo's derived quantities must be current: mj_forward)."""
        d = self._d
        force = d.qfrc_actuator + d.qfrc_applied
        energy = float(d.energy[0] + d.energy[1]) + self.stored()
        return energy, force.copy(), d.qpos[self._pos_qpos].copy(), d.qvel.copy(), float(d.qfrc_damper @ d.qvel)

    def stored(self) -> float:
        """J: the energy the cable limits store now, ½ Σ f·r over their active rows (needs mj_forward)."""
        d = self._d
        rows = d.efc_type == self._limit
        if not rows.any():
            return 0.0
        return 0.5 * float(d.efc_force[rows] @ np.maximum(-d.efc_pos[rows], 0.0))

    def start(self) -> None:
        """Before a step (or a run of steps with the same input): the state after mj_forward."""
        self._last = self._sample()

    def after_step(self, h: float) -> None:
        """After one mj_step of h seconds: brings MuJoCo's derived quantities to the new state
        (mj_forward) and books the step's constraint work."""
        self._mj.mj_forward(self._m, self._d)
        now = self._sample()
        if self._last is not None:
            e0, f0, p0, v0, damp0 = self._last
            e1, f1, p1, v1, damp1 = now
            pos, rot = self._pos_dof, self._rot_dof
            w_forces = 0.5 * float((f0[pos] + f1[pos]) @ (p1 - p0))
            w_forces += 0.5 * h * float(f0[rot] @ v0[rot] + f1[rot] @ v1[rot])
            w_damping = 0.5 * h * (damp0 + damp1)
            self.work += (e1 - e0) - w_forces - w_damping
        self._last = now
