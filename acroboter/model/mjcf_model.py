"""An MJCF model (MuJoCo's XML) of any spec: the same crane for a second, independent engine.

    xml = mjcf_xml(spec)                        # a string; mujoco.MjModel.from_xml_string(xml)

What each part of the spec becomes (docs/mujoco.md explains why, and what makes the two agree):

- a rigid body: a body whose frame is its centre of mass and whose axes are u, v, w, with its mass
  and full inertia tensor; a free joint carrying its damping (the model's dissipation
  ½ c_t |ṙ|² + ½ c_r |ω|² is exactly joint damping on a free joint's six velocities), or three
  slide joints and a ball joint where the translational and rotational damping differ (a free
  joint has one damping for all six);
- a fixed anchor: a world site; a moving anchor: a body on slide joints along the axes it follows,
  whose position and velocity the plant prescribes at every MuJoCo step (a mocap body would be
  MuJoCo's idiom, but its constraint solver does not see a mocap body's velocity: the main cable
  to a mocap anchor moving at 0.1 m/s stretched by 0.68 µm at a 0.1 ms step and 11 µm at 1 ms,
  against 0.00 and 0.03 µm for the driven body);
- a cable of fixed length L: a spatial tendon between its ends with the length limit L, a
  unilateral constraint (it pulls, never pushes, as the project's plant);
- a winch cable: a slide joint, its length coordinate, carrying the drum's reflected inertia as
  armature, in a massless drum body on the first end's body; the cable is routed from the drum over
  the first end to the second (a spatial tendon through three sites) whose limit keeps the free
  span at most the paid-out length, so the cable can go slack. A second, unconstrained tendon
  draws the free span;
- actuators in the spec's order with its gains and limits (`ctrlrange`): a winch tension pulls its
  length coordinate in (gear −gain), a thrust is a force along the body axis at its point, a
  torque a moment about the body axis (site transmissions in body axes).

The XML is deterministic: the same spec gives the same bytes (no dates, no paths, shortest
round-trip numbers).
"""

from __future__ import annotations

import math
import sys
from xml.sax.saxutils import quoteattr

import numpy as np

from .layout import build_layout, nominal_coordinates
from .physical import DRUM_END_M, drum_capacities
from .ranges import MUJOCO_TIMESTEP, mujoco_work_problem
from .spec import BodyThrust, BodyTorque, Spec, SpecError, WinchTension

# The constraint and integration settings the agreement with the project's plant was measured at
# (docs/mujoco.md): RK4, a Newton solver run to round-off, and cable limits as stiff as MuJoCo allows
# at the time step (a time constant of two steps, critically damped, impedance near 1).
DEFAULT_TIMESTEP = 1e-4  # s
MAX_TIMESTEP = MUJOCO_TIMESTEP.high  # s: beyond, the cables' constraint time constant is too soft to call them cables
SOLVER_TOLERANCE = 1e-12
SOLVER_ITERATIONS = 100
# The cable limits' solref is (2·timestep, CABLE_DAMPRATIO): MuJoCo raises a time constant below two steps
# to two steps anyway.
CABLE_DAMPRATIO = 1.0
CABLE_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
# A moving anchor's slide joints: inertia so large that the cables' pull changes its motion by less
# than round-off within one step (the plant resets it to the prescribed motion at every step).
ANCHOR_ARMATURE = 1e9
# MuJoCo wants a positive mass on every moving body; the drum's own mass (its inertia is the armature).
DRUM_MASS = 1e-9

AXIS_VECTOR = {"u": (1.0, 0.0, 0.0), "v": (0.0, 1.0, 0.0), "w": (0.0, 0.0, 1.0)}


class MjcfError(SpecError):
    """A valid spec that MuJoCo cannot represent as it stands (names the part and the fix; exit 2)."""


def _num(x: float) -> str:
    x = float(x)
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if abs(x) < sys.float_info.min:
        # zero, never "-0.0"; a subnormal (a drawn anchor height of 5e-324 m) MuJoCo's parser refuses as "too large",
        # and it is no length a crane has
        return "0"
    text = repr(x)
    return text[:-2] if text.endswith(".0") else text


def _vec(values) -> str:
    return " ".join(_num(v) for v in values)


def _attrs(**attrs) -> str:
    return "".join(f" {k.rstrip('_')}={quoteattr(str(v))}" for k, v in attrs.items() if v is not None)


def drum_joint(cable: str) -> str:
    return f"{cable}.length"


def routing_tendon(cable: str) -> str:
    return f"{cable}.routing"


def joint_layout(spec: Spec) -> dict[str, str]:
    """Per body: 'free' (one free joint) or 'slide+ball' (damping that differs between translation and
    rotation)."""
    return {b.name: "free" if b.damping.translational == b.damping.rotational else "slide+ball" for b in spec.bodies}


def check_representable(spec: Spec, source: str = "") -> None:
    """What the spec's own validation leaves to MuJoCo: every cable spans a distance at qpos0 (the
    initial configuration), or MuJoCo's tendon has no direction there."""
    layout = build_layout(spec)
    points = _world_points(spec, layout, nominal_coordinates(spec, layout))
    problems = []
    for i, cable in enumerate(spec.cables):
        a, b = cable.ends
        span = float(np.linalg.norm(points[a] - points[b]))
        if span < 1e-9:
            problems.append((f"cables[{i}] ({cable.name}).ends", f"expected ends apart in the initial configuration "
                             f"(MuJoCo's tendon needs a direction), found '{a}' and '{b}' {span:.3g} m apart: move "
                             "a body point or an initial position"))
        capacity = cable.winch.capacity if cable.winch is not None else None
        if capacity is not None and span >= capacity - DRUM_END_M:
            problems.append((f"cables[{i}] ({cable.name}).winch.capacity",
                             f"expected more than the cable's length in the initial configuration, {span:.6g} m (the "
                             f"drum holds the cable it starts with), found {capacity:g} m"))
    if problems:
        raise MjcfError(source or spec.name, problems)


def _world_points(spec: Spec, layout, q: np.ndarray) -> dict[str, np.ndarray]:
    points = {a.name: np.array(a.position, dtype=float) for a in spec.anchors}
    for body in spec.bodies:
        i = layout.body_offset[body.name]
        r, axes = q[i : i + 3], q[i + 3 : i + 12].reshape(3, 3)  # rows u, v, w
        for name in body.points:
            points[f"{body.name}.{name}"] = r + np.array(body.point(name)) @ axes
    return points


def mjcf_xml(spec: Spec, timestep: float = DEFAULT_TIMESTEP, start: tuple[np.ndarray, np.ndarray] | None = None) -> str:
    """The MJCF model of `spec` (see the module's docstring); `timestep` sets MuJoCo's step and the
    cables' constraint time constant (two steps). The model's reference pose (qpos0) is the spec's
    initial configuration, or with `start` = (q, u) (natural coordinates and inputs, e.g. the static
    equilibrium) that pose, with a keyframe `static_start` holding u as ctrl."""
    MUJOCO_TIMESTEP.check(timestep, "MuJoCo time step")  # a RangeError (ValueError), as the work per period:
    if (problem := mujoco_work_problem(timestep, 1.0 / spec.controller.rate_hz)) is not None:
        raise ValueError(f"MuJoCo time step: {problem}")
    check_representable(spec)
    layout = build_layout(spec)
    q0 = nominal_coordinates(spec, layout) if start is None else np.asarray(start[0], dtype=float)
    if q0.shape != (layout.n,) or not np.isfinite(q0).all():
        raise ValueError(f"start: expected {layout.n} finite coordinates, found shape {q0.shape}")
    joints = joint_layout(spec)
    solref = _vec((2 * timestep, CABLE_DAMPRATIO))
    solimp = _vec(CABLE_SOLIMP)
    ceiling = max([a.position[2] for a in spec.anchors] or [max(b.initial_position[2] for b in spec.bodies) + 1.0])
    weight = sum(b.mass for b in spec.bodies)
    scale = max(0.05, 0.1 * max(np.cbrt(b.mass / 1000.0) * 2 for b in spec.bodies))  # marker size, m

    out: list[str] = []
    w = out.append
    _head(w, spec, timestep, ceiling, scale)
    for anchor in spec.anchors:
        _anchor(w, spec, layout, q0, anchor, scale)
    for body in spec.bodies:
        _body(w, spec, layout, q0, body, joints[body.name], weight)
    w("  </worldbody>")
    _tendons(w, spec, layout, q0, solref, solimp)
    _actuators(w, spec)
    if start is not None:  # the pose is qpos0 already; the key adds the inputs that hold it
        u = np.asarray(start[1], dtype=float)
        if u.shape != (len(spec.actuators),) or not np.isfinite(u).all():
            raise ValueError(f"start: expected {len(spec.actuators)} finite inputs, found shape {u.shape}")
        w(f'  <keyframe><key name="static_start" ctrl="{_vec(u)}"/></keyframe>')
    w("</mujoco>")
    return "\n".join(out) + "\n"


def _head(w, spec: Spec, timestep: float, ceiling: float, scale: float) -> None:
    """The model's options, visuals, defaults, and the world's light and ceiling."""
    w(f"<!-- Generated by acroboter from model spec '{spec.name}' (spec model hash {spec.model_hash()}).")
    w("     Do not edit: run `make generate` (or `acroboter mjcf SPEC -o FILE`). -->")
    w(f"<mujoco{_attrs(model=spec.name)}>")
    w('  <compiler angle="radian" autolimits="false" inertiafromgeom="false"/>')
    w(f"  <option{_attrs(timestep=_num(timestep), gravity=_vec(spec.gravity), integrator='RK4', solver='Newton')}"
      f"{_attrs(tolerance=_num(SOLVER_TOLERANCE), iterations=SOLVER_ITERATIONS, ls_tolerance=_num(1e-10))}"
      f"{_attrs(jacobian='dense', cone='pyramidal')}>")
    w('    <flag contact="disable"/>')  # the crane's geoms are pictures; nothing touches in this model
    w("  </option>")
    w(f'  <visual><global offwidth="1280" offheight="720"/><map znear="0.01"/>'
      f'<scale framelength="{_num(2 * scale)}" framewidth="{_num(0.1 * scale)}"/></visual>')
    w("  <default>")
    w('    <geom contype="0" conaffinity="0" group="1"/>')
    w('    <site group="2" size="0.01"/>')
    w("  </default>")
    w("  <worldbody>")
    w(f'    <light pos="0 0 {_num(ceiling + 3)}" dir="0 0 -1" directional="true"/>')
    w(f'    <geom name="ceiling" type="plane" pos="0 0 {_num(ceiling)}" size="3 3 0.01" rgba="0.8 0.8 0.85 0.3"/>')


def _anchor(w, spec: Spec, layout, q0: np.ndarray, anchor, scale: float) -> None:
    """A fixed anchor (a site), or a moving one (a body on slide joints along the axes it follows, prescribed by
    the plant), with the drums of the winches whose first end it is."""
    if not anchor.follows_path:
        w(f"    <site{_attrs(name=anchor.name, pos=_vec(anchor.position), size='0.02')}/>")
        _drums(w, spec, layout, q0, parent=anchor.name, first_end_at=np.array(anchor.position), indent="    ")
        return
    w(f"    <body{_attrs(name=anchor.name, pos=_vec(anchor.position))}>")
    for axis in sorted(anchor.follows_path):
        direction = {"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}[axis]
        w(f"      <joint{_attrs(name=f'{anchor.name}.{axis}', type='slide', axis=direction)}"
          f"{_attrs(armature=_num(ANCHOR_ARMATURE), limited='false')}/>")
    w(f'      <inertial pos="0 0 0" mass="{_num(DRUM_MASS)}" diaginertia="{_vec([DRUM_MASS] * 3)}"/>')
    w(f"      <site{_attrs(name=anchor.name, size='0.02')}/>")
    w(f'      <geom type="box" size="{_vec([2 * scale, 2 * scale, 0.5 * scale])}" rgba="0.4 0.4 0.45 1"/>')
    _drums(w, spec, layout, q0, parent=anchor.name, first_end_at=np.zeros(3), indent="      ")
    w("    </body>")


def _body(w, spec: Spec, layout, q0: np.ndarray, body, joint: str, weight: float) -> None:
    """A body: its frame the centre of mass and its axes u, v, w (at qpos0: the start pose), its joints, inertia,
    picture, the sites of its points and actuators, the drums of the winches whose first end it is."""
    i = layout.body_offset[body.name]
    r, rot = q0[i : i + 3], q0[i + 3 : i + 12].reshape(3, 3).T  # columns u, v, w
    w(f"    <body{_attrs(name=body.name, pos=_vec(r), quat=_vec(_quat(rot)))}>")
    if joint == "free":
        w(f"      <joint{_attrs(name=body.name, type='free', damping=_num(body.damping.translational))}/>")
    else:  # slides along the world axes (rot's rows in body axes), then a ball joint
        for axis, row in zip("xyz", rot, strict=True):
            w(f"      <joint{_attrs(name=f'{body.name}.{axis}', type='slide', axis=_vec(row))}"
              f"{_attrs(damping=_num(body.damping.translational), limited='false')}/>")
        w(f"      <joint{_attrs(name=f'{body.name}.rotation', type='ball')}"
          f"{_attrs(damping=_num(body.damping.rotational), limited='false')}/>")
    inertia = np.array(body.inertia, dtype=float)
    full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
    w(f"      <inertial{_attrs(pos='0 0 0', mass=_num(body.mass), fullinertia=_vec(full))}/>")
    radius = max([float(np.linalg.norm(body.point(p)[:2])) for p in body.points] or [0.0]) or 0.1
    colour = "0.85 0.45 0.2 0.6" if body.mass < 0.5 * weight else "0.2 0.45 0.85 0.6"
    # A flat disc through the body's points: a picture, with no mass (inertiafromgeom is off).
    w(f"      <geom{_attrs(name=f'{body.name}.shape', type='cylinder', size=_vec([radius, 0.1 * radius]))}"
      f"{_attrs(rgba=colour)}/>")
    w(f"      <site{_attrs(name=f'{body.name}.com', pos='0 0 0')}/>")
    for name in sorted(body.points):
        w(f"      <site{_attrs(name=f'{body.name}.{name}', pos=_vec(body.point(name)))}/>")
    for act in spec.actuators:  # force and moment in the body's axes, at the thrust's point
        if isinstance(act, BodyThrust) and act.body == body.name:
            w(f"      <site{_attrs(name=f'{act.name}.site', pos=_vec(act.point))}/>")
        if isinstance(act, BodyTorque) and act.body == body.name:
            w(f"      <site{_attrs(name=f'{act.name}.site', pos='0 0 0')}/>")
    _drums(w, spec, layout, q0, parent=body.name, first_end_at=None, indent="      ")
    w("    </body>")


def _tendons(w, spec: Spec, layout, q0: np.ndarray, solref: str, solimp: str) -> None:
    """Each cable a spatial tendon between its ends' sites; a winch's also a routing tendon over its drum, whose
    limit is the drum's capacity."""
    w("  <tendon>")
    for cable in spec.cables:
        a, b = cable.ends  # the sites are named as the ends: 'climbing_unit', 'CC.a1'
        if cable.winch is None:
            w(f"    <spatial{_attrs(name=cable.name, limited='true', range=_vec([0.0, cable.length]))}"
              f"{_attrs(solreflimit=solref, solimplimit=solimp, width='0.004', rgba='0.1 0.1 0.1 1')}>")
            w(f'      <site site="{a}"/><site site="{b}"/>')
            w("    </spatial>")
            continue
        capacity = drum_capacities(spec)[cable.name]
        w(f"    <spatial{_attrs(name=routing_tendon(cable.name), limited='true', range=_vec([0.0, capacity]))}"
          f"{_attrs(solreflimit=solref, solimplimit=solimp, width='0.002', rgba='0 0 0 0')}>")
        w(f'      <site site="{cable.name}.drum"/><site site="{a}"/><site site="{b}"/>')
        w("    </spatial>")
        w(f"    <spatial{_attrs(name=cable.name, limited='false', width='0.004', rgba='0.1 0.1 0.1 1')}>")
        w(f'      <site site="{a}"/><site site="{b}"/>')
        w("    </spatial>")
    w("  </tendon>")


def _actuators(w, spec: Spec) -> None:
    """Each input a general actuator: a winch on its drum's joint, a thrust or torque at its site, with the
    spec's limits as ctrlrange."""
    w("  <actuator>")
    for act in spec.actuators:
        low, high = act.resolved_limits()
        limited = {"ctrllimited": "true", "ctrlrange": _vec([low, high])} if (
            math.isfinite(low) or math.isfinite(high)) else {"ctrllimited": "false"}
        if isinstance(act, WinchTension):
            w(f"    <general{_attrs(name=act.name, joint=drum_joint(act.cable), gear=_num(-act.gain), **limited)}/>")
        elif isinstance(act, BodyThrust):
            gear = [act.gain * c for c in AXIS_VECTOR[act.axis]] + [0.0, 0.0, 0.0]
            w(f"    <general{_attrs(name=act.name, site=f'{act.name}.site', gear=_vec(gear), **limited)}/>")
        else:
            gear = [0.0, 0.0, 0.0] + [act.gain * c for c in AXIS_VECTOR[act.axis]]
            w(f"    <general{_attrs(name=act.name, site=f'{act.name}.site', gear=_vec(gear), **limited)}/>")
    w("  </actuator>")


def _drums(w, spec, layout, q0, parent: str, first_end_at, indent: str) -> None:
    """The drum bodies of the winch cables whose first end is on `parent` (a body, or an anchor at
    `first_end_at` in the parent's frame): a slide joint (the cable length, with the drum's reflected
    inertia as armature) along the parent's −z axis, its site `capacity − L` above the first end."""
    for cable in spec.cables:
        if cable.winch is None or cable.ends[0].split(".", 1)[0] != parent:
            continue
        first = cable.ends[0]
        local = np.array(spec.body(parent).point(first.split(".", 1)[1]), dtype=float) if "." in first else (
            np.asarray(first_end_at, dtype=float))
        length0 = float(q0[layout.winch_index[cable.name]])
        up = np.array([0.0, 0.0, 1.0])
        pos = local + (drum_capacities(spec)[cable.name] - length0) * up
        w(f"{indent}<body{_attrs(name=f'{cable.name}.drum', pos=_vec(pos))}>")
        w(f"{indent}  <joint{_attrs(name=drum_joint(cable.name), type='slide', axis=_vec(-up))}"
          f"{_attrs(ref=_num(length0), armature=_num(cable.winch.reflected_inertia), limited='false')}/>")
        w(f'{indent}  <inertial pos="0 0 0" mass="{_num(DRUM_MASS)}" diaginertia="{_vec([DRUM_MASS] * 3)}"/>')
        w(f"{indent}  <site{_attrs(name=f'{cable.name}.drum')}/>")
        w(f"{indent}</body>")


def _quat(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method, deterministic)."""
    m = np.asarray(rot, dtype=float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    return tuple(float(c) for c in q)
