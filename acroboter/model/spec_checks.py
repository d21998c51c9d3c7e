"""The checks that need the whole spec: names referenced but not defined, duplicates, zero-length cables,
the path's anchors, the integral gain, the sensing groups. Each problem is (field path, text), as the
schema's (acroboter.model.spec joins both into one SpecError).
"""

from __future__ import annotations

import math

import numpy as np

from .ranges import baumgarte_problem, damping_problem, delay_problem, sampled_gain_problems
from .schema import (
    MAX_CONTROL_STEPS,
    MAX_PLANT_SUBSTEPS,
    TASK_COMPONENTS,
    Body,
    LevelTask,
    PositionTask,
    Sensing,
    Spec,
    WinchTension,
    YawTask,
    integral_gain_problem,
    sensing_coordinates,
)


def body_rotation(yaw_deg: float) -> np.ndarray:
    """Rotation about the world z axis; its columns are the body axes u, v, w."""
    a = math.radians(yaw_deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _end_position(spec: Spec, end: str) -> np.ndarray:
    """World position of a cable end in the initial configuration."""
    if "." not in end:
        return np.array(spec.anchor(end).position)
    body_name, point_name = end.split(".", 1)
    body = spec.body(body_name)
    return np.array(body.initial_position) + body_rotation(body.initial_yaw_deg) @ np.array(body.point(point_name))


def listing(names) -> str:
    names = list(dict.fromkeys(names))  # each once, in order
    return ", ".join(f"'{n}'" for n in names) if names else "none"


def check_references(spec: Spec) -> list[tuple[str, str]]:
    """Every problem across the spec's tables, in the spec's order: names, cables, actuators, the task, the path and
    the timing, the controller, the sensing."""
    refs = _References(spec)
    problems = _duplicate_names(spec)
    problems += refs.cable_problems()
    problems += refs.actuator_problems()
    problems += refs.task_problems()
    problems += _path_and_timing_problems(spec)
    problems += _controller_problems(spec)
    return problems


def _duplicate_names(spec: Spec) -> list[tuple[str, str]]:
    """Names used twice. Bodies and anchors share one namespace (a cable end names either)."""
    problems: list[tuple[str, str]] = []
    for kind, named in (
        ("body or anchor", [(f"bodies[{i}].name", b.name) for i, b in enumerate(spec.bodies)]
         + [(f"anchors[{i}].name", a.name) for i, a in enumerate(spec.anchors)]),
        ("cable", [(f"cables[{i}].name", c.name) for i, c in enumerate(spec.cables)]),
        ("actuator", [(f"actuators[{i}].name", a.name) for i, a in enumerate(spec.actuators)]),
    ):
        first: dict[str, str] = {}
        for path, name in named:
            if name in first:
                problems.append(
                    (path, f"expected a unique {kind} name, found '{name}' again (first used at {first[name]})")
                )
            else:
                first[name] = path
    return problems


class _References:
    """The names a spec defines (with duplicates, the first definition counts), and the checks of the names that
    refer to them; each check appends to `problems` and says whether the name was found."""

    def __init__(self, spec: Spec):
        self.spec = spec
        self.problems: list[tuple[str, str]] = []
        self.bodies: dict[str, Body] = {}
        for b in spec.bodies:
            self.bodies.setdefault(b.name, b)
        self.anchors = [a.name for a in spec.anchors]
        self.cables = {}
        for c in spec.cables:
            self.cables.setdefault(c.name, c)

    def _taken(self) -> list[tuple[str, str]]:
        problems, self.problems = self.problems, []
        return problems

    def body_ok(self, path: str, name: str) -> bool:
        if name not in self.bodies:
            self.problems.append((path, f"expected a defined body ({listing(self.bodies)}), found '{name}'"))
            return False
        return True

    def end_ok(self, path: str, end: str) -> bool:
        if "." in end:
            body_name, point_name = end.split(".", 1)
            if not self.body_ok(path, body_name):
                return False
            if point_name not in self.bodies[body_name].points:
                known = listing(self.bodies[body_name].points)
                self.problems.append(
                    (path, f"expected a point of body '{body_name}' (defined: {known}), found '{point_name}'")
                )
                return False
            return True
        if end not in self.anchors:
            self.problems.append(
                (path, f"expected a defined anchor ({listing(self.anchors)}) or 'body.point', found '{end}'")
            )
            return False
        return True

    def cable_problems(self) -> list[tuple[str, str]]:
        """Each cable: a length or a winch, ends that exist, on two different owners, apart at the start."""
        spec = self.spec
        for i, cable in enumerate(spec.cables):
            base = f"cables[{i}] ({cable.name})"
            if (cable.length is None) == (cable.winch is None):
                self.problems.append(
                    (base, "expected exactly one of 'length' (fixed cable) or 'winch' (length is a coordinate), "
                     f"found {'both' if cable.length is not None else 'neither'}")
                )
            if all([self.end_ok(f"{base}.ends[{k}]", e) for k, e in enumerate(cable.ends)]):
                self._cable_ends(spec, base, cable)
        return self._taken()

    def _cable_ends(self, spec: Spec, base: str, cable) -> None:
        owners = [e.split(".", 1)[0] if "." in e else None for e in cable.ends]
        if owners == [None, None]:
            self.problems.append((f"{base}.ends",
                                  f"expected a cable that connects a body, found two anchors {cable.ends}"))
        elif owners[0] == owners[1]:
            self.problems.append(
                (f"{base}.ends", f"expected a cable between two different bodies (or an anchor and a body), "
                 f"found both ends on body '{owners[0]}': {cable.ends}")
            )
        elif cable.winch is not None:
            length0 = float(np.linalg.norm(_end_position(spec, cable.ends[0]) - _end_position(spec, cable.ends[1])))
            if length0 < 1e-9:
                self.problems.append(
                    (f"{base}.ends", f"expected a positive initial cable length, found {length0:.3g} m: "
                     f"{cable.ends[0]} and {cable.ends[1]} coincide in the initial configuration")
                )

    def actuator_problems(self) -> list[tuple[str, str]]:
        """Each actuator: what it drives exists (a winch's cable, once), its preferred value within its limits, a
        winch's limits never pushing."""
        spec = self.spec
        driven: dict[str, str] = {}
        winches = [c.name for c in spec.cables if c.winch is not None]
        for i, act in enumerate(spec.actuators):
            base = f"actuators[{i}] ({act.name})"
            if not isinstance(act, WinchTension):
                self.body_ok(f"{base}.body", act.body)
                continue
            if act.cable not in self.cables:
                found = "which is not a defined cable"
            elif self.cables[act.cable].winch is None:
                found = "a fixed-length cable without a winch"
            elif act.cable in driven:
                self.problems.append(
                    (f"{base}.cable", f"expected one winch_tension actuator per cable, found cable '{act.cable}' "
                     f"already driven by {driven[act.cable]}")
                )
                continue
            else:
                driven[act.cable] = base
                continue
            self.problems.append((f"{base}.cable", f"expected a cable with a winch ({listing(winches)}), "
                                                   f"found '{act.cable}', {found}"))
        for i, act in enumerate(spec.actuators):
            self.problems += _limit_problems(i, act)
        return self._taken()

    def task_problems(self) -> list[tuple[str, str]]:
        """The task's bodies exist; exactly one position task (the point the path moves)."""
        for i, task in enumerate(self.spec.task):
            self.body_ok(f"task[{i}] ({task.kind}).body", task.body)
        positions = [t for t in self.spec.task if isinstance(t, PositionTask)]
        if len(positions) != 1:
            given = ", ".join(t.kind for t in self.spec.task)
            self.problems.append(
                ("task", "expected exactly one servo-constraint of kind 'position' (the point the path moves), "
                 f"found {len(positions)} (kinds given: {given})")
            )
        return self._taken()


def _limit_problems(i: int, act) -> list[tuple[str, str]]:
    problems = []
    low, high = act.resolved_limits()
    if act.preferred is not None and not low <= act.preferred <= high:
        problems.append((f"actuators[{i}] ({act.name}).preferred",
                         f"expected a value within the limits [{low:g}, {high:g}], found {act.preferred:g}"))
    if isinstance(act, WinchTension) and (low < 0 if act.gain > 0 else high > 0):
        side = "min >= 0" if act.gain > 0 else "max <= 0 (the gain is negative)"
        problems.append((f"actuators[{i}] ({act.name}).limits",
                         f"expected limits that never make the cable push (a winch only pulls: {side}), "
                         f"found [{low:g}, {high:g}] with gain {act.gain:g}"))
    return problems


def _path_and_timing_problems(spec: Spec) -> list[tuple[str, str]]:
    """A path that moves, a plant step that divides the control period, a path of 1 to MAX_CONTROL_STEPS steps, a
    gravity within 1000 m/s², the moving anchors' axes."""
    problems: list[tuple[str, str]] = []
    waypoints = np.array(spec.path.waypoints, dtype=float)
    if not (np.linalg.norm(np.diff(waypoints, axis=0), axis=1) > 0).any():
        problems.append(
            ("path.waypoints", "expected at least two distinct waypoints (the path moves the tracked point; a "
             f"yaw-only path is not supported), found {len(waypoints)} equal ones")
        )
    period = 1.0 / spec.controller.rate_hz
    substeps = round(period / spec.simulation.step)
    if substeps < 1 or not math.isclose(substeps * spec.simulation.step, period, rel_tol=1e-9):
        problems.append(("simulation.step", f"expected a plant step that divides the control period 1/rate_hz = "
                                            f"{period:g} s, found {spec.simulation.step:g} s"))
    elif substeps > MAX_PLANT_SUBSTEPS:
        problems.append(("simulation.step", f"expected at most {MAX_PLANT_SUBSTEPS} plant steps per control period, "
                                            f"found {substeps} ({spec.simulation.step:g} s in {period:g} s)"))
    problems += _stiffness_problems(spec)
    length = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
    steps = length / spec.path.mean_speed * spec.controller.rate_hz
    if length > 0 and not steps >= 1:
        problems.append(("path.mean_speed", f"expected a path of at least one control step, found "
                                            f"{length:g} m at {spec.path.mean_speed:g} m/s: "
                                            f"{steps:.3g} steps at {spec.controller.rate_hz:g} Hz; lower mean_speed"))
    if steps > MAX_CONTROL_STEPS:
        problems.append(("path", f"expected a path of at most {MAX_CONTROL_STEPS} control steps, found "
                                 f"{length:g} m at {spec.path.mean_speed:g} m/s and "
                                 f"{spec.controller.rate_hz:g} Hz = {steps:.3g} steps: raise mean_speed or lower "
                                 "rate_hz"))
    if np.linalg.norm(spec.gravity) > 1e3:
        problems.append(("gravity", f"expected a gravity of at most 1000 m/s², found {np.linalg.norm(spec.gravity):g}"))
    for i, anchor in enumerate(spec.anchors):
        if len(set(anchor.follows_path)) != len(anchor.follows_path):
            problems.append((f"anchors[{i}].follows_path", f"expected each axis once, found {anchor.follows_path}"))
    return problems


def _controller_problems(spec: Spec) -> list[tuple[str, str]]:
    """The servo law stable sampled at the rate, ki within Routh–Hurwitz, the saturation priority, the sensing (its
    delay shorter than the path)."""
    c = spec.controller
    problems = list(sampled_gain_problems(c.kp, c.kd, c.rate_hz))
    if (problem := integral_gain_problem(c.kp, c.kd, c.ki)) is not None:
        problems.append(("controller.ki", problem))
    if (problem := priority_problem(spec, c.underactuation.priority)) is not None:
        problems.append(("controller.underactuation.priority", problem))
    if spec.sensing is not None:
        problems += sensing_problems(spec, spec.sensing)
        waypoints = np.array(spec.path.waypoints, dtype=float)
        length = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
        duration = length / spec.path.mean_speed
        if length > 0 and (problem := delay_problem(spec.sensing.delay_periods, c.rate_hz, duration,
                                                    what="path")) is not None:
            problems.append(("sensing.delay_periods", problem))
    return problems


DEFAULT_PRIORITY = ("horizontal", "level", "height", "yaw")  # keep the position, release yaw, then the height


def task_components(spec: Spec) -> dict[str, list[int]]:
    """The servo-constraint rows of each task component a saturation priority names (TASK_COMPONENTS), in the
    layout's row order (acroboter.model.layout): a position task's x, y rows are 'horizontal', its z row
    'height'; a level task's two rows 'level'; a yaw task's row 'yaw'. Only the components the task has."""
    rows: dict[str, list[int]] = {}
    row = 0
    for task in spec.task:
        if isinstance(task, PositionTask):
            rows.setdefault("horizontal", []).extend([row, row + 1])
            rows.setdefault("height", []).append(row + 2)
            row += 3
        elif isinstance(task, YawTask):
            rows.setdefault("yaw", []).append(row)
            row += 1
        elif isinstance(task, LevelTask):
            rows.setdefault("level", []).extend([row, row + 1])
            row += 2
    return {name: rows[name] for name in TASK_COMPONENTS if name in rows}


def resolved_priority(spec: Spec, priority=None) -> tuple[str, ...]:
    """The task components, most important first: `priority` (default the spec's, else DEFAULT_PRIORITY's order
    restricted to the components the task has)."""
    priority = spec.controller.underactuation.priority if priority is None else priority
    present = task_components(spec)
    if priority is None:
        return tuple(name for name in DEFAULT_PRIORITY if name in present)
    return tuple(priority)


def priority_problem(spec: Spec, priority) -> str | None:
    """Why a saturation priority does not fit the task (None if it does): each of the task's components once."""
    if priority is None:
        return None
    present = list(task_components(spec))
    repeated = sorted({p for p in priority if list(priority).count(p) > 1})
    absent = [p for p in priority if p not in present]
    missing = [p for p in present if p not in priority]
    if not (repeated or absent or missing):
        return None
    found = []
    if repeated:
        found.append(f"{listing(repeated)} more than once")
    if absent:
        found.append(f"{listing(absent)}, which the task does not have")
    if missing:
        found.append(f"no {listing(missing)}")
    return (f"expected each component of the task once, most important first ({listing(present)}; e.g. "
            f"{list(DEFAULT_PRIORITY)}), found {'; '.join(found)}")


def _stiffness_problems(spec: Spec) -> list[tuple[str, str]]:
    """What the plant's fixed RK4 step cannot integrate: the Baumgarte stabilisation's fastest pole, a body's
    damping rate (damping over its mass, or over its smallest principal moment)."""
    sim = spec.simulation
    problems: list[tuple[str, str]] = []
    if (problem := baumgarte_problem(sim.baumgarte_zeta, sim.baumgarte_omega, sim.step)) is not None:
        problems.append(("simulation.baumgarte_omega", problem))
    for i, body in enumerate(spec.bodies):
        smallest = float(np.linalg.eigvalsh(np.array(body.inertia, dtype=float))[0])
        for kind, inertia, what in (("translational", body.mass, "mass"),
                                    ("rotational", smallest, "smallest principal moment")):
            damping = getattr(body.damping, kind)
            if (problem := damping_problem(damping, inertia, sim.step, what)) is not None:
                problems.append((f"bodies[{i}].damping.{kind}", problem))
    return problems


def sensing_problems(spec: Spec, sensing: Sensing) -> list[tuple[str, str]]:
    """Names in a sensing section: known selectors, each coordinate and each group name once."""
    problems: list[tuple[str, str]] = []
    seen: dict[str, str] = {}
    names: set[str] = set()
    for i, group in enumerate(sensing.groups):
        where = f"sensing.groups[{i}] ({group.name})"
        if group.name in names:
            problems.append((f"{where}.name", f"expected a group name used once, found '{group.name}' again"))
        names.add(group.name)
        for j, selector in enumerate(group.coordinates):
            found = sensing_coordinates(spec, selector)
            if found is None:
                problems.append((f"{where}.coordinates[{j}]", "expected '<body>', '<body>.r|u|v|w', "
                                 "'<body>.r_x' … or '<winch cable>.length' (bodies: "
                                 f"{listing(b.name for b in spec.bodies)}; winch cables: "
                                 f"{listing(c.name for c in spec.cables if c.winch is not None)}), "
                                 f"found '{selector}'"))
                continue
            for name in found:
                if name in seen:
                    problems.append((f"{where}.coordinates[{j}]", f"expected each coordinate in one group, found "
                                     f"{name} also in group '{seen[name]}'"))
                    break
                seen[name] = group.name
    return problems
