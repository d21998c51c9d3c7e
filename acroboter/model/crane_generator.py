"""Cranes nobody drew: a random crane of the ACROBOTER kind as a spec (`generated_crane`), for the fuzz over
crane geometries (acroboter.studies.generated_cranes, `acroboter plant-fuzz --cranes N`) and the tests' hypothesis
strategy (tests/crane_strategy.py draws through the same function, so hypothesis can shrink a crane).

What varies, each within a range a real crane of this kind could have (the spec's schema states far wider ones,
the windows outside which a number is a unit slip, acroboter.model.ranges):

- 3 to 6 winch cables between the connector (CC) and the swinging unit (SU), their anchors spread around each
  body at irregular angles and heights (neighbours at least a third of the even spacing apart), the SU's
  anchors on a circle 0.2-1.2x the CC's and twisted against them;
- the ceiling, the main cable's length and the drop between the anchor planes;
- masses, and inertias of boxes of random sides turned to random axes (off-diagonal terms);
- each drum's reflected inertia, log-uniform from light to heavy, and the bodies' damping (0 included);
- the tension limits and preferred tension of a redundant crane (more than 3 winches) around its static share.

The task (the SU's position, yaw and level), the inputs besides the winches (yaw torque, two thrusts), the controller
and the plant's step are the paper's crane's; the path is the paper's, scaled to the crane's connector. Whether a
crane has a static equilibrium with every cable pulling is the statics' question
(acroboter.studies.generated_cranes.check_crane), not this module's.
"""

from __future__ import annotations

import math
import random
from typing import Protocol

import numpy as np

from .spec import Spec, parse_spec

# The ranges drawn (SI units); `Ranges` documents each.
WINCHES = (3, 6)
CEILING_M = (2.2, 5.0)
MAIN_CABLE_M = (0.4, 2.5)
CC_MASS_KG = (2.0, 40.0)
SU_MASS_KG = (0.5, 25.0)
BOX_SIDE_M = (0.08, 0.8)  # a body's inertia is a box's of these sides (its mass), turned to random axes
CC_RADIUS_M = (0.12, 0.7)  # the connector's winch anchors
SU_RADIUS_FRACTION = (0.2, 1.2)  # the unit's anchors, of the connector's radius
TOP_HEIGHT_M = (0.1, 0.6)  # the main cable's point above the connector's centre
ANCHOR_HEIGHT_M = 0.06  # ± a winch anchor's height off its body's plane
DROP_M = (0.25, 1.5)  # between the two anchor planes
TWIST_DEG = 25.0  # ± the unit's anchors turned against the connector's
REFLECTED_INERTIA_KG = (0.005, 1.0)  # log-uniform: a light drum is the plants' hardest case
TRANSLATIONAL_DAMPING = (0.0, 2.0)  # N·s/m
ROTATIONAL_DAMPING = (0.0, 0.5)  # N·m·s
# A redundant crane's tension limits and preferred tension, × its static share (the unit's weight / winches): the
# distribution pulls the spare inputs towards `preferred` and the limits keep every cable pulling.
SHARE_LIMITS = (0.2, 20.0)
SHARE_PREFERRED = 1.2
PAPER_RADIUS_M = 0.30  # the paper's connector radius: its path is scaled by CC radius / this
PAPER_DURATION_S = 55.0  # the paper's path takes this long whatever its scale (mean speed scaled with it)


class Draw(Protocol):
    """Where a crane's numbers come from: `random.Random` (RandomDraw) or hypothesis (tests/crane_strategy.py)."""

    def uniform(self, low: float, high: float) -> float: ...
    def integer(self, low: int, high: int) -> int: ...


class RandomDraw:
    """Draws from a `random.Random(seed)`: crane `seed` is the same crane on every machine."""

    def __init__(self, seed: int):
        self.rng = random.Random(seed)

    def uniform(self, low: float, high: float) -> float:
        return self.rng.uniform(low, high)

    def integer(self, low: int, high: int) -> int:
        return self.rng.randint(low, high)


def crane_name(seed: int) -> str:
    return f"crane_{seed}"


def generated_crane(draw: Draw, name: str, winches: tuple[int, int] = WINCHES) -> dict:
    """A crane's spec, as the TOML file's tables (parse_spec reads it): see the module docstring. `winches`: the
    range of its number of winch cables (within WINCHES)."""
    winches = draw.integer(max(winches[0], WINCHES[0]), min(winches[1], WINCHES[1]))
    ceiling, main = draw.uniform(*CEILING_M), draw.uniform(*MAIN_CABLE_M)
    cc_mass, su_mass = draw.uniform(*CC_MASS_KG), draw.uniform(*SU_MASS_KG)
    cc_inertia, su_inertia = _box_inertia(draw, cc_mass), _box_inertia(draw, su_mass)
    radius = draw.uniform(*CC_RADIUS_M)
    su_radius = radius * draw.uniform(*SU_RADIUS_FRACTION)
    top = draw.uniform(*TOP_HEIGHT_M)
    drop = draw.uniform(*DROP_M)
    angles = _anchor_angles(draw, winches)
    twist = draw.uniform(-TWIST_DEG, TWIST_DEG)
    cc_z = ceiling - main - top
    su_z = cc_z - drop
    cc_points: dict = {"top": [0.0, 0.0, _round(top)]}
    su_points: dict = {}
    for i, angle in enumerate(angles, start=1):
        cc_points[f"a{i}"] = {"radius": _round(radius), "angle_deg": _round(angle),
                              "height": _round(draw.uniform(-ANCHOR_HEIGHT_M, ANCHOR_HEIGHT_M))}
        su_points[f"b{i}"] = {"radius": _round(su_radius), "angle_deg": _round(_wrapped(angle + twist)),
                              "height": _round(draw.uniform(-ANCHOR_HEIGHT_M, ANCHOR_HEIGHT_M))}
    cables = [{"name": "main", "ends": ["climbing_unit", "CC.top"], "length": _round(main)}]
    actuators = []
    share = su_mass * 9.81 / winches
    for i in range(1, winches + 1):
        drum = math.exp(draw.uniform(*(math.log(v) for v in REFLECTED_INERTIA_KG)))
        cables.append({"name": f"L{i}", "ends": [f"CC.a{i}", f"SU.b{i}"], "winch": {"reflected_inertia": _round(drum)}})
        winch = {"name": f"tension_{i}", "kind": "winch_tension", "cable": f"L{i}"}
        if winches > 3:
            winch |= {"limits": [_round(SHARE_LIMITS[0] * share), _round(SHARE_LIMITS[1] * share)],
                      "preferred": _round(SHARE_PREFERRED * share)}
        actuators.append(winch)
    actuators += [{"name": "yaw_torque", "kind": "body_torque", "body": "SU", "axis": "w"},
                  {"name": "thrust_u", "kind": "body_thrust", "body": "SU", "axis": "u"},
                  {"name": "thrust_v", "kind": "body_thrust", "body": "SU", "axis": "v"}]
    scale = radius / PAPER_RADIUS_M
    return {
        "name": name,
        "description": f"a generated crane: {winches} winches, CC {cc_mass:.3g} kg, SU {su_mass:.3g} kg",
        "gravity": [0.0, 0.0, -9.81],
        "anchors": [{"name": "climbing_unit", "position": [0.0, 0.0, _round(ceiling)], "follows_path": ["x", "y"]}],
        "bodies": [
            _body(draw, "CC", cc_mass, cc_inertia, cc_z, cc_points),
            _body(draw, "SU", su_mass, su_inertia, su_z, su_points),
        ],
        "cables": cables,
        "actuators": actuators,
        "task": [{"kind": "position", "body": "SU"}, {"kind": "yaw", "body": "SU", "axis": "u"},
                 {"kind": "level", "body": "SU", "axis": "w"}],
        "path": {"waypoints": [[_round(scale * c) for c in p] for p in PAPER_WAYPOINTS],
                 "mean_speed": _round(PAPER_LENGTH_M * scale / PAPER_DURATION_S), "yaw_deg": 90.0},
        "controller": {"rate_hz": 50.0, "kp": 5.0, "kd": 5.0,
                       "penalty": {"alpha_geometric": 1.0e7, "alpha_servo": 1.0e7, "omega": 10.0, "mu": 1.0,
                                   "iterations": [3, 4, 5], "recovery": "projected", "kappa": 0.5}},
        "simulation": {"step": 0.002, "baumgarte_zeta": 1.0, "baumgarte_omega": 20.0},
    }


def crane_spec(seed: int) -> Spec:
    """Generated crane `seed` (RandomDraw(seed)), validated: a SpecError here is the generator's bug."""
    name = crane_name(seed)
    return parse_spec(generated_crane(RandomDraw(seed), name), f"{name} (acroboter.model.crane_generator)")


# The paper's path (docs/model.md §5): a 0.25 m square, then the same 0.1 m higher, and back down.
PAPER_WAYPOINTS = [
    [0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.25, 0.25, 0.0], [0.0, 0.25, 0.0], [0.0, 0.0, 0.0],
    [0.0, 0.0, 0.1], [0.25, 0.0, 0.1], [0.25, 0.25, 0.1], [0.0, 0.25, 0.1], [0.0, 0.0, 0.1],
    [0.0, 0.0, 0.0],
]
PAPER_LENGTH_M = sum(math.dist(a, b) for a, b in zip(PAPER_WAYPOINTS, PAPER_WAYPOINTS[1:], strict=False))


def _body(draw: Draw, name: str, mass: float, inertia: np.ndarray, z: float, points: dict) -> dict:
    return {"name": name, "mass": _round(mass), "inertia": inertia.tolist(), "initial_position": [0.0, 0.0, _round(z)],
            "damping": {"translational": _round(draw.uniform(*TRANSLATIONAL_DAMPING)),
                        "rotational": _round(draw.uniform(*ROTATIONAL_DAMPING))},
            "points": points}


def _box_inertia(draw: Draw, mass: float) -> np.ndarray:
    """A solid box's inertia (sides drawn from BOX_SIDE_M) about its centre, turned to axes drawn at random:
    off-diagonal terms, and the triangle inequality of any rigid body.
    Rounded to 6 significant digits, kept symmetric."""
    a, b, c = (draw.uniform(*BOX_SIDE_M) for _ in range(3))
    principal = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * mass / 12.0
    yaw, pitch, roll = (draw.uniform(-math.pi, math.pi) for _ in range(3))
    rot = _rotation_z(yaw) @ _rotation_y(pitch) @ _rotation_z(roll)
    inertia = rot @ principal @ rot.T
    rounded = np.vectorize(_round)(0.5 * (inertia + inertia.T))
    return np.triu(rounded) + np.triu(rounded, 1).T


def _anchor_angles(draw: Draw, winches: int) -> list[float]:
    """Angles (deg) around the body: even spacing, turned as a whole, each moved by up to a third of the spacing
    either way (neighbours stay at least a third of the spacing apart)."""
    spacing = 360.0 / winches
    turn = draw.uniform(0.0, spacing)
    return [_wrapped(turn + i * spacing + draw.uniform(-spacing / 3, spacing / 3)) for i in range(winches)]


def _wrapped(angle: float) -> float:
    return (angle + 180.0) % 360.0 - 180.0


def _rotation_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rotation_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _round(value: float) -> float:
    """6 significant digits: a generated spec reads (and writes to TOML) as a person's would."""
    return float(f"{value:.6g}")
