"""MuJoCo as the plant: the spec's MJCF model (acroboter.model.mjcf_model) stepped by MuJoCo, read in
the project's natural coordinates, with the interface of acroboter.sim.plant.Plant.

    plant = MujocoPlant(model, path)            # model: a CompiledModel (for its spec and layout)
    x = plant.initial_state(q0)                 # [q, q̇] in natural coordinates
    plant.advance(x, u, h, table, first, steps) # `steps`·h seconds of MuJoCo with u held (ZOH)

The controllers see only x, as from the project's own plant: body centres and axes from MuJoCo's
body frames (which are the centres of mass and the axes u, v, w), the winch lengths from their
slide joints. A moving anchor's slide joints are set to the path's prescribed position and velocity
at every MuJoCo step, with its acceleration as an applied force on its huge inertia (docs/mujoco.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.path import DesiredPath
from ..model.mjcf_model import DEFAULT_TIMESTEP, drum_joint, joint_layout, mjcf_xml, routing_tendon
from ..model.physical import DRUM_END_M, with_parameters
from .plant import SimulationError, StageTable, drum_ran_out, stage_rows, stage_table

# A cable is taut where its limit pulls (force above SLACK_FORCE_N, N) or where it is stretched to its
# length within TAUT_GAP_M (m): MuJoCo adds a limit's row only once the cable is past its length, so at
# an exactly taut start the row appears only within the first step.
SLACK_FORCE_N = 1e-9
TAUT_GAP_M = 1e-9


def _mujoco():
    """mujoco, or MissingExtraError (an ImportError naming `pip install 'acroboter[mujoco]'`) without it."""
    from ..process.extras import require

    require("mujoco", "the MuJoCo plant (MujocoPlant)")
    try:
        import mujoco
    except ImportError as err:  # installed but broken (a missing shared library, say)
        raise SimulationError(f"the mujoco package is installed but does not import ({err}): "
                              "pip install --force-reinstall 'acroboter[mujoco]'") from None
    return mujoco


@dataclass
class _Body:
    offset: int  # first natural coordinate of the body
    body_id: int
    free: bool
    qpos: int  # qpos address of the free joint, or of the first slide joint
    dof: int
    ball_qpos: int = -1
    ball_dof: int = -1
    origin: np.ndarray | None = None  # slide+ball: body position at qpos0
    frame0: np.ndarray | None = None  # slide+ball: body axes at qpos0 (columns)


class MujocoPlant:
    """The crane of `model.spec` (with `parameters`, acroboter.model.physical) simulated by MuJoCo."""

    def __init__(self, model, path: DesiredPath, parameters=None, timestep: float = DEFAULT_TIMESTEP):
        mujoco = _mujoco()
        self._mj = mujoco
        self.model, self.path = model, path
        self.parameters: dict[str, float] = {name: float(v) for name, v in (parameters or {}).items()}
        self.physical_spec = with_parameters(model.spec, self.parameters)
        self.timestep = float(timestep)
        self.xml = mjcf_xml(self.physical_spec, self.timestep)
        self.mj_model = mujoco.MjModel.from_xml_string(self.xml)
        self.mj_data = mujoco.MjData(self.mj_model)
        lay = model.layout
        self.layout = lay
        self.n = lay.n
        self.state_size = 2 * self.n
        m = self.mj_model
        name2id = mujoco.mj_name2id
        obj = mujoco.mjtObj
        joints = joint_layout(self.physical_spec)
        self._bodies: list[_Body] = []
        for body in self.physical_spec.bodies:
            bid = name2id(m, obj.mjOBJ_BODY, body.name)
            if joints[body.name] == "free":
                j = name2id(m, obj.mjOBJ_JOINT, body.name)
                self._bodies.append(_Body(lay.body_offset[body.name], bid, True, m.jnt_qposadr[j], m.jnt_dofadr[j]))
            else:
                jx = name2id(m, obj.mjOBJ_JOINT, f"{body.name}.x")
                jb = name2id(m, obj.mjOBJ_JOINT, f"{body.name}.rotation")
                self._bodies.append(_Body(lay.body_offset[body.name], bid, False, m.jnt_qposadr[jx], m.jnt_dofadr[jx],
                                          m.jnt_qposadr[jb], m.jnt_dofadr[jb], m.body_pos[bid].copy(),
                                          _matrix(mujoco, m.body_quat[bid])))
        self._winches = []  # (coordinate index, qpos address, dof address, capacity, cable)
        for cable in self.physical_spec.cables:
            if cable.winch is not None:
                j = name2id(m, obj.mjOBJ_JOINT, drum_joint(cable.name))
                t = name2id(m, obj.mjOBJ_TENDON, routing_tendon(cable.name))
                self._winches.append((lay.winch_index[cable.name], m.jnt_qposadr[j], m.jnt_dofadr[j],
                                      float(m.tendon_range[t, 1]), cable.name))
        self._anchors = []  # (signal index, qpos address, dof address, start coordinate)
        for anchor in self.physical_spec.anchors:
            if anchor.follows_path:
                j0 = lay.anchor_signal[anchor.name]
                for axis in sorted(anchor.follows_path):
                    c = "xyz".index(axis)
                    j = name2id(m, obj.mjOBJ_JOINT, f"{anchor.name}.{axis}")
                    self._anchors.append((j0 + c, m.jnt_qposadr[j], m.jnt_dofadr[j], float(anchor.position[c]),
                                          float(m.dof_armature[m.jnt_dofadr[j]])))
        self.cable_names = [c.name for c in self.physical_spec.cables]
        self._cable_tendon = np.array([
            name2id(m, obj.mjOBJ_TENDON, routing_tendon(c.name) if c.winch is not None else c.name)
            for c in self.physical_spec.cables])
        nc = len(self.cable_names)
        self.start_tension = np.zeros(nc)
        self.start_active = np.ones(nc)
        self.impact_energy = 0.0  # MuJoCo's soft limits leave no impact of their own to record
        self.transitions = np.zeros(nc, dtype=np.int64)
        self._last_active = np.ones(nc)
        self._limit_type = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON)
        self._velocity = np.zeros(6)
        self._ctrl_low, self._ctrl_high, _ = self.physical_spec.input_limits()
        self.cable_gap = np.zeros(nc)  # m, > 0 stretched: tendon length − its limit, end of the last advance
        self.limits_enforced = True
        self.ledger = None  # a ConstraintWork (acroboter.sim.mujoco_energy) books every MuJoCo step's constraint work

    def set_cable_dampratio(self, ratio: float) -> None:
        """The damping ratio of the cables' soft limits (the MJCF's is CABLE_DAMPRATIO, critical). A snap
        taut of a limit with no load behind it rebounds with a restitution that depends on the ratio
        alone (13.5 % at 1, 4.8 % at 2, 0.38 % at 8; the own plant's impact has 0); a larger ratio lowers
        the limit's stiffness instead, and the stretch a snap leaves creeps back over ~2·timeconst·ratio²
        (acroboter.studies.plant_differential.cable_dampratio). The time constant (two steps) is kept."""
        if not (math.isfinite(ratio) and ratio > 0):
            raise ValueError(f"cable damping ratio: expected a positive number, found {ratio}")
        self.mj_model.tendon_solref_lim[self._cable_tendon, 1] = ratio

    def release_limits(self) -> None:
        """Take inputs beyond the spec's limits as they are (open loop: what the user asks), with
        MuJoCo's ctrlrange clamp off, instead of refusing them."""
        self.limits_enforced = False
        self.mj_model.opt.disableflags |= int(self._mj.mjtDisableBit.mjDSBL_CLAMPCTRL)

    # --- state --------------------------------------------------------------------------------
    def initial_state(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> np.ndarray:
        """x = [q, q̇] at rest (or at qd0), with MuJoCo's state set from it at t = 0."""
        x = np.zeros(self.state_size)
        x[: self.n] = q0
        if qd0 is not None:
            x[self.n :] = qd0
        self.set_state(x[: self.n], x[self.n :], 0.0)
        # As the own plant: every cable starts taut, with no tension recorded before the first step.
        self.start_tension[:] = 0.0
        self.start_active[:] = 1.0
        self._last_active[:] = 1.0
        self.transitions[:] = 0
        self._update_gap()
        return x

    def set_state(self, q: np.ndarray, qd: np.ndarray, t: float) -> None:
        """MuJoCo's qpos, qvel from natural coordinates (the axes are re-orthonormalised through a
        quaternion) and the moving anchors at the path's position at t."""
        mj, m, d = self._mj, self.mj_model, self.mj_data
        mj.mj_resetData(m, d)
        d.time = t
        quat = np.zeros(4)
        for b in self._bodies:
            i = b.offset
            r, rot = q[i : i + 3], q[i + 3 : i + 12].reshape(3, 3).T  # columns u, v, w
            omega = 0.5 * sum(np.cross(rot[:, k], qd[i + 3 + 3 * k : i + 6 + 3 * k]) for k in range(3))
            if b.free:
                d.qpos[b.qpos : b.qpos + 3] = r
                mj.mju_mat2Quat(quat, np.ascontiguousarray(rot).reshape(-1))
                d.qpos[b.qpos + 3 : b.qpos + 7] = quat
                d.qvel[b.dof : b.dof + 3] = qd[i : i + 3]
                d.qvel[b.dof + 3 : b.dof + 6] = rot.T @ omega
            else:
                d.qpos[b.qpos : b.qpos + 3] = r - b.origin
                mj.mju_mat2Quat(quat, np.ascontiguousarray(b.frame0.T @ rot).reshape(-1))
                d.qpos[b.ball_qpos : b.ball_qpos + 4] = quat
                d.qvel[b.dof : b.dof + 3] = qd[i : i + 3]
                d.qvel[b.ball_dof : b.ball_dof + 3] = rot.T @ omega
        for index, qpos, dof, _, _ in self._winches:
            d.qpos[qpos], d.qvel[dof] = q[index], qd[index]
        if self._anchors:
            row = self.path.table(np.array([t]))[0]
            self._prescribe(row)
        mj.mj_forward(m, d)

    def natural_state(self, x: np.ndarray) -> None:
        """Write MuJoCo's current state into x = [q, q̇] (natural coordinates; needs mj_forward)."""
        mj, m, d = self._mj, self.mj_model, self.mj_data
        n = self.n
        vel = self._velocity
        for b in self._bodies:
            i = b.offset
            rot = d.xmat[b.body_id].reshape(3, 3)
            x[i : i + 3] = d.xpos[b.body_id]
            x[i + 3 : i + 12] = rot.T.reshape(-1)  # u, v, w: the columns
            mj.mj_objectVelocity(m, d, mj.mjtObj.mjOBJ_BODY, b.body_id, vel, 0)  # [ω, v] world-aligned
            x[n + i : n + i + 3] = vel[3:]
            for k in range(3):
                x[n + i + 3 + 3 * k : n + i + 6 + 3 * k] = np.cross(vel[:3], rot[:, k])
        for index, qpos, dof, _, _ in self._winches:
            x[index], x[n + index] = d.qpos[qpos], d.qvel[dof]

    # --- stepping -----------------------------------------------------------------------------
    def stage_rows(self, h: float, first_step: int, steps: int) -> StageTable:
        """The path's signals at the own plant's RK4 stage times (simulate reads the desired path and the
        anchors from it; MuJoCo's steps evaluate the path at their own times)."""
        return stage_rows(self.path, h, first_step, steps)

    def stage_table(self, t0: float, h: float, steps: int) -> StageTable:
        return stage_table(self.path, t0, h, steps)

    def advance(self, x: np.ndarray, u: np.ndarray, h: float, table: np.ndarray, first_step: int,
                steps: int, t0: float | None = None) -> None:
        """steps·h seconds of MuJoCo from the table's start time (+ first_step·h) with u held; x is
        overwritten with the state at the end. MuJoCo keeps its own state between calls (x is its
        output, not re-read, so that nothing is lost converting back and forth)."""
        mj, m, d = self._mj, self.mj_model, self.mj_data
        if t0 is None:
            t0 = getattr(table, "t0", None)
            t0 = 0.0 if t0 is None else t0
        start = t0 + first_step * h
        duration = steps * h
        count = round(duration / self.timestep)
        if count < 1 or not math.isclose(count * self.timestep, duration, rel_tol=1e-9):
            raise SimulationError(f"MuJoCo's time step {self.timestep:g} s must divide the plant step {h:g} s")
        if self.limits_enforced:
            self._check_limits(u, start)
        d.ctrl[:] = u
        mj.mj_forward(m, d)
        self._read_tensions()
        ledger = self.ledger
        if ledger is not None:
            ledger.start()
        if self._anchors or ledger is not None:
            rows = self.path.table(start + self.timestep * np.arange(count)) if self._anchors else None
            for j in range(count):
                if rows is not None:
                    self._prescribe(rows[j])
                mj.mj_step(m, d)
                if ledger is not None:
                    ledger.after_step(self.timestep)  # leaves MuJoCo forwarded at the new state
        else:
            mj.mj_step(m, d, count)
        if ledger is None:
            mj.mj_forward(m, d)
        self._check(start + duration)
        self.natural_state(x)

    def step(self, x: np.ndarray, t: float, u: np.ndarray, h: float) -> None:
        """h seconds from t with u held (convenience: MuJoCo's time is taken to be t)."""
        self.advance(x, u, h, self.stage_table(t, h, 1), 0, 1)

    def probe(self, x: np.ndarray, u: np.ndarray, t: float) -> None:
        """The cable tensions at MuJoCo's current state with input u (x is MuJoCo's last output)."""
        self.mj_data.ctrl[:] = u
        self._mj.mj_forward(self.mj_model, self.mj_data)
        self._read_tensions()

    # --- internals ------------------------------------------------------------------------------
    def _check_limits(self, u: np.ndarray, t: float) -> None:
        """MuJoCo clips ctrl to ctrlrange without a word: an input beyond the spec's limits is an error
        here instead (the controllers keep within them; round-off of 1e-9 relative is let through)."""
        low, high = self._ctrl_low, self._ctrl_high
        slack = 1e-9 * np.maximum(1.0, np.abs(u))
        beyond = (u < low - slack) | (u > high + slack)
        if beyond.any():
            i = int(np.argmax(beyond))
            name = self.layout.inputs[i]
            raise SimulationError(f"at t = {t:.3f} s input {name} = {u[i]:.6g} {self.layout.input_units[i]} is beyond "
                                  f"its limits [{low[i]:g}, {high[i]:g}], which MuJoCo would clip: keep inputs within "
                                  "the spec's actuators[].limits")

    def _prescribe(self, row: np.ndarray) -> None:
        ns = self.layout.n_signals
        d = self.mj_data
        for signal, qpos, dof, start, armature in self._anchors:
            d.qpos[qpos] = row[signal] - start
            d.qvel[dof] = row[ns + signal]
            d.qfrc_applied[dof] = armature * row[2 * ns + signal]

    def _read_tensions(self) -> None:
        d = self.mj_data
        self.start_tension[:] = 0.0
        nefc = d.nefc
        if nefc:
            types, ids, forces = d.efc_type[:nefc], d.efc_id[:nefc], d.efc_force[:nefc]
            for c, tendon in enumerate(self._cable_tendon):
                rows = np.flatnonzero((types == self._limit_type) & (ids == tendon))
                if rows.size:
                    self.start_tension[c] = forces[rows].sum()
        gap = self.mj_model.tendon_range[self._cable_tendon, 1] - d.ten_length[self._cable_tendon]
        self.start_active[:] = (self.start_tension > SLACK_FORCE_N) | (gap < TAUT_GAP_M)
        self.transitions += self.start_active != self._last_active
        self._last_active[:] = self.start_active

    def _update_gap(self) -> None:
        tendons = self._cable_tendon
        self.cable_gap[:] = self.mj_data.ten_length[tendons] - self.mj_model.tendon_range[tendons, 1]

    def _check(self, t: float) -> None:
        d = self.mj_data
        self._update_gap()
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            raise SimulationError(f"MuJoCo's state became non-finite at t = {t:.3f} s")
        for _, qpos, _, capacity, cable in self._winches:
            if d.qpos[qpos] >= capacity - DRUM_END_M:
                raise drum_ran_out(cable, float(d.qpos[qpos]), capacity, t)


def _matrix(mujoco, quat: np.ndarray) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z), by MuJoCo."""
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(quat, dtype=float))
    return out.reshape(3, 3)
