"""Model spec: parse a crane's TOML file, validate it, and report every problem by field path.

Field-level checks (types, unknown keys, positivity, inertia) are pydantic validators; checks that
need the whole spec (names referenced but not defined, duplicates, zero-length cables) run after
parsing. Both end up as one `SpecError` that lists each problem as `path: expected …, found …`.

This module reads a file and joins the parts: the schema (acroboter.model.schema), the whole-spec checks
(acroboter.model.spec_checks) and pydantic's errors in the spec's words (acroboter.model.spec_errors).
Their names are importable from here.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import ValidationError

from .schema import (
    ACTUATOR_KINDS,
    AXES,
    INERTIA_MARGIN,
    LENGTH_LIMIT,
    MASS_RANGE,
    MAX_CONTROL_STEPS,
    MAX_ITERATIONS,
    MAX_NAME_LENGTH,
    MAX_PLANT_SUBSTEPS,
    MAX_SENSING_DELAY,
    NAME_PATTERN,
    PATH_SIGNALS,
    POINT_FORMS,
    RECOVERIES,
    SATURATIONS,
    SENSING_VECTORS,
    TASK_COMPONENTS,
    TASK_KINDS,
    Actuator,
    Anchor,
    Body,
    BodyPoint,
    BodyThrust,
    BodyTorque,
    Cable,
    Controller,
    Coordinate,
    Damping,
    Length,
    LevelTask,
    Limit,
    Mass,
    Name,
    PathSpec,
    Penalty,
    PolarPoint,
    Position,
    PositionTask,
    Sensing,
    SensingGroup,
    ServoConstraint,
    Simulation,
    Spec,
    SpecError,
    Underactuation,
    Vec3,
    Winch,
    WinchTension,
    YawTask,
    integral_gain_problem,
    sensing_coordinates,
)
from .spec_checks import body_rotation, check_references, sensing_problems
from .spec_errors import format_pydantic

# The schema's names, and the checks', are the spec's: `from acroboter.model.spec import Spec, load_spec, ...`.
__all__ = [
    "ACTUATOR_KINDS",
    "AXES",
    "Actuator",
    "Anchor",
    "Body",
    "BodyPoint",
    "BodyThrust",
    "BodyTorque",
    "Cable",
    "Controller",
    "Coordinate",
    "Damping",
    "INERTIA_MARGIN",
    "LENGTH_LIMIT",
    "Length",
    "LevelTask",
    "Limit",
    "MASS_RANGE",
    "MAX_CONTROL_STEPS",
    "MAX_ITERATIONS",
    "MAX_NAME_LENGTH",
    "MAX_PLANT_SUBSTEPS",
    "MAX_SENSING_DELAY",
    "Mass",
    "NAME_PATTERN",
    "Name",
    "PATH_SIGNALS",
    "POINT_FORMS",
    "PathSpec",
    "Penalty",
    "PolarPoint",
    "Position",
    "PositionTask",
    "RECOVERIES",
    "SATURATIONS",
    "SENSING_VECTORS",
    "Sensing",
    "SensingGroup",
    "ServoConstraint",
    "Simulation",
    "Spec",
    "SpecError",
    "Underactuation",
    "TASK_COMPONENTS",
    "TASK_KINDS",
    "Vec3",
    "Winch",
    "WinchTension",
    "YawTask",
    "body_rotation",
    "check_references",
    "format_pydantic",
    "integral_gain_problem",
    "load_spec",
    "parse_spec",
    "sensing_coordinates",
    "sensing_problems",
]

def parse_spec(data: dict, source: str = "<spec>") -> Spec:
    """Validate a spec given as a dict; raise SpecError with every problem found."""
    try:
        spec = Spec.model_validate(data)
    except ValidationError as err:
        raise SpecError(source, format_pydantic(err, data)) from None
    problems = check_references(spec)
    if problems:
        raise SpecError(source, problems)
    return spec


MAX_SPEC_BYTES = 2**20  # 1 MB: the largest spec the caps allow is far smaller


def load_spec(path: str | Path) -> Spec:
    """Read and validate a TOML spec file."""
    path = Path(path)
    if not path.is_file():
        what = ("a folder" if path.is_dir() else "a device or a pipe, not a file" if path.exists() else
                "nothing")
        raise SpecError(str(path), [("(file)", f"expected a readable TOML file, found {what} at this path")])
    if (size := path.stat().st_size) > MAX_SPEC_BYTES:  # read only a bounded file: a spec is a few kB
        raise SpecError(str(path), [("(file)", f"expected a TOML spec of at most {MAX_SPEC_BYTES // 2**20} MB, "
                                               f"found {size / 2**20:.0f} MB")])
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # -sig: a byte-order mark (Windows editors) goes
    except tomllib.TOMLDecodeError as err:
        raise SpecError(str(path), [("(syntax)", f"expected valid TOML, found a syntax error: {err}")]) from None
    except RecursionError:  # tomllib parses nesting recursively: 500 levels of [[[...]]] exhausted the stack
        raise SpecError(str(path), [("(syntax)", "expected a TOML spec, found arrays or tables nested too deep for "
                                                 "the parser (a spec nests a few levels)")]) from None
    except (OSError, UnicodeDecodeError) as err:
        raise SpecError(str(path), [("(file)", f"expected a readable UTF-8 TOML file, found: {err}")]) from None
    return parse_spec(data, str(path))
