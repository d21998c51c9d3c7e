"""A malformed spec is rejected with one specific message per problem: field path, expected, found.

Each case mutates the dict of model_spec/acroboter.toml and checks the message's content, not just
that validation fails. The CLI must print those problems and exit 2 without a traceback.
"""

from __future__ import annotations

import copy
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass

import pytest
from conftest import REPO, SHIPPED_SPECS, raw_spec

from acroboter.model.spec import RECOVERIES, SpecError, load_spec, parse_spec


def _set(*path, value):
    """A mutation that sets d[path...] = value."""

    def mutate(d):
        for key in path[:-1]:
            d = d[key]
        d[path[-1]] = value

    return mutate


def _pop(*path):
    def mutate(d):
        for key in path[:-1]:
            d = d[key]
        del d[path[-1]]

    return mutate


def _append(key, index):
    """Append a copy of d[key][index] (a duplicate name)."""
    return lambda d: d[key].append(copy.deepcopy(d[key][index]))


def _both(*mutations):
    def mutate(d):
        for m in mutations:
            m(d)

    return mutate


@dataclass
class Case:
    id: str
    mutate: Callable[[dict], None]
    path: str  # the problem's field path, exactly
    words: list[str]  # all must occur in the message
    only: bool = True  # the spec has no other problem


CASES = [
    # --- keys and types ---
    Case("unknown key", _set("bodies", 0, "colour", value="red"), "bodies[0].colour",
         ["unknown key 'colour'", "known keys", "mass", "inertia"]),
    Case("unknown top-level key", _set("colour", value="red"), "colour",
         ["unknown key 'colour'", "bodies", "actuators"]),
    Case("unknown key in a polar point", _set("bodies", 0, "points", "a1", value={"radius": 0.3, "angle": 90.0}),
         "bodies[0].points.a1.angle", ["unknown key 'angle'", "angle_deg"], only=False),
    Case("missing key", _pop("bodies", 1, "mass"), "bodies[1].mass", ["required", "missing"]),
    Case("missing key in a nested table", _pop("controller", "penalty", "omega"), "controller.penalty.omega",
         ["required", "missing"]),
    Case("wrong type: string for a number", _set("bodies", 1, "mass", value="heavy"), "bodies[1].mass",
         ["expected a number", "'heavy'", "string"]),
    Case("wrong type: boolean for a number", _set("bodies", 1, "mass", value=True), "bodies[1].mass",
         ["expected a number", "True", "boolean"]),
    Case("wrong type: number-like string", _set("bodies", 0, "mass", value="10"), "bodies[0].mass",
         ["expected a number", "'10'", "string"]),
    Case("wrong type: scalar for a vector", _set("gravity", value="down"), "gravity",
         ["expected an array", "'down'"]),
    Case("vector of 2", _set("bodies", 1, "initial_position", value=[0.0, 0.35]), "bodies[1].initial_position",
         ["3 numbers [x, y, z]", "found 2 item"]),
    Case("not a finite number", _set("bodies", 1, "initial_position", value=[0.0, float("inf"), 0.35]),
         "bodies[1].initial_position[1]", ["expected -1e4 <= coordinate <= 1e4 (m)", "found inf"]),
    Case("bad name", _set("name", value="my crane"), "name", ["letters, digits", "'my crane'"]),
    Case("malformed point", _set("bodies", 0, "points", "top", value="up"), "bodies[0].points.top",
         ["[x, y, z]", "radius, angle_deg", "'up'"]),
    Case("point with 2 coordinates", _set("bodies", 0, "points", "top", value=[0.0, 0.4]), "bodies[0].points.top",
         ["3 numbers", "found 2 item"]),
    Case("cable with 3 ends", _set("cables", 1, "ends", value=["CC.a1", "SU.b1", "SU.b2"]), "cables[1].ends",
         ["2 ends", "found 3 item"]),
    Case("actuator that is not a table", _set("actuators", 0, value="tension"), "actuators[0]",
         ["expected a table", "'tension'"]),
    # --- physical values ---
    Case("zero mass", _set("bodies", 1, "mass", value=0), "bodies[1].mass",
         ["expected 1e-6 <= mass <= 1e6 (kg)", "found 0"]),
    Case("negative mass", _set("bodies", 1, "mass", value=-8.0), "bodies[1].mass", ["1e-6 <= mass", "found -8"]),
    Case("mass in grams", _set("bodies", 1, "mass", value=8000000.0), "bodies[1].mass",
         ["mass <= 1e6 (kg)", "found 8e+06"]),
    Case("flat lamina inertia", _set("bodies", 1, "inertia", value=[[0.1, 0, 0], [0, 0.25, 0], [0, 0, 0.35]]),
         "bodies[1].inertia", ["strictly", "flat lamina", "condition number"]),
    Case("position in millimetres", _set("bodies", 0, "initial_position", value=[0.0, 0.0, 11000.0]),
         "bodies[0].initial_position[2]", ["coordinate <= 1e4 (m)", "found 11000"]),
    Case("name too long", _set("name", value="a" * 65), "name", ["at most 64 characters", "found 65"]),
    Case("iteration count beyond the cap", _set("controller", "penalty", "iterations", value=[3, 100000000]),
         "controller.penalty.iterations[1]", ["iterations <= 1000", "found 100000000"]),
    Case("plant step that does not divide the period", _set("simulation", "step", value=0.003),
         "simulation.step", ["divides the control period", "0.02 s", "found 0.003 s"]),
    Case("plant step far too small", _set("simulation", "step", value=1e-7),
         "simulation.step", ["at most 10000 plant steps", "found 200000"]),
    Case("plant step below its range", _set("simulation", "step", value=1e-9),
         "simulation.step", ["expected 1e-8 <= step <= 10 (s)", "found 1e-09"]),
    Case("path of no control step", lambda d: (d["path"].update(mean_speed=100.0,
                                                                waypoints=[[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]])),
         "path.mean_speed", ["at least one control step", "lower mean_speed"]),
    Case("absurd path speed", _set("path", "mean_speed", value=1e300), "path.mean_speed",
         ["expected 1e-4 <= mean_speed <= 100 (m/s)"]),
    Case("task point in millimetres", _set("task", 0, "point", value=[0.0, 0.0, 50000.0]),
         "task[0].point[2]", ["coordinate <= 1e4"]),
    Case("path too long for the records", _set("path", "mean_speed", value=1e-4),
         "path", ["at most 360000 control steps", "raise mean_speed"]),
    Case("inertia not symmetric", _set("bodies", 1, "inertia", value=[[0.2, 0.01, 0], [0, 0.2, 0], [0, 0, 0.35]]),
         "bodies[1].inertia", ["symmetric", "[0][1] = 0.01", "[1][0] = 0"]),
    Case("inertia not positive definite",
         _set("bodies", 1, "inertia", value=[[0.2, 0, 0], [0, -0.2, 0], [0, 0, 0.35]]),
         "bodies[1].inertia", ["positive definite", "principal moments -0.2"]),
    Case("inertia singular", _set("bodies", 0, "inertia", value=[[0.3, 0.3, 0], [0.3, 0.3, 0], [0, 0, 0.5]]),
         "bodies[0].inertia", ["positive definite", "principal moments"]),
    Case("inertia violates the triangle inequality",
         _set("bodies", 1, "inertia", value=[[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.35]]),
         "bodies[1].inertia", ["triangle inequality", "I1 + I2 >= I3", "0.1 + 0.1 < 0.35"]),
    Case("inertia of 2 rows", _set("bodies", 1, "inertia", value=[[0.2, 0, 0], [0, 0.2, 0]]), "bodies[1].inertia",
         ["3x3 matrix", "found 2 item"]),
    Case("zero-length fixed cable", _set("cables", 0, "length", value=0.0), "cables[0].length",
         ["expected 1e-6 <= length <= 1e4 (m)", "found 0"]),
    Case("winch cable whose ends coincide at the start",
         # SU.b1 = (0, 0.15, 0.05) in SU axes; move the SU so that it sits on CC.a1 = (0, 0.3, 1.1)
         _set("bodies", 1, "initial_position", value=[0.0, 0.15, 1.05]), "cables[1] (L1).ends",
         ["positive initial cable length", "CC.a1", "SU.b1", "coincide"]),
    Case("negative damping", _set("bodies", 0, "damping", "rotational", value=-0.5),
         "bodies[0].damping.rotational", ["expected 0 <= damping <= 1e6", "found -0.5"]),
    # --- what the plant's step and the control rate can integrate (acroboter.model.ranges) ---
    Case("damping too stiff for the plant step", _set("bodies", 1, "damping", "translational", value=20000.0),
         "bodies[1].damping.translational", ["expected 0 <= damping <= 1.04e4", "found 20000", "RK4"]),
    Case("Baumgarte too fast for the plant step", _set("simulation", "baumgarte_omega", value=5000.0),
         "simulation.baumgarte_omega", ["expected 0 < baumgarte_omega <= 1300 (1/s)", "found 5000", "RK4"]),
    Case("kd the control rate cannot sample", _set("controller", "kd", value=60.0), "controller.kd",
         ["expected 0.125 < kd < 50 (1/s)", "found 60", "sampled at rate_hz = 50 Hz"]),
    Case("kd too small for kp", _set("controller", "kd", value=0.1), "controller.kd",
         ["expected 0.125 < kd < 50 (1/s)", "found 0.1", "or kp below 4.472"]),
    Case("sensing delay as long as the path", _both(_set("path", "mean_speed", value=1.0), _set("sensing", value={
        "groups": [{"name": "all", "coordinates": ["SU", "CC"]}], "delay_periods": 110})),
         "sensing.delay_periods", ["expected a whole number 0 <= delay_periods <= 109", "2.2 s path"]),
    # --- references ---
    Case("cable end on an undefined body", _set("cables", 1, "ends", value=["XX.a1", "SU.b1"]),
         "cables[1] (L1).ends[0]", ["defined body", "'CC', 'SU'", "found 'XX'"]),
    Case("cable end on an undefined point", _set("cables", 1, "ends", value=["CC.a9", "SU.b1"]),
         "cables[1] (L1).ends[0]", ["point of body 'CC'", "'a1', 'a2', 'a3'", "found 'a9'"]),
    Case("cable end on an undefined anchor", _set("cables", 0, "ends", value=["skyhook", "CC.top"]),
         "cables[0] (main).ends[0]", ["defined anchor", "'climbing_unit'", "found 'skyhook'"]),
    Case("cable between two anchors", _set("cables", 0, "ends", value=["climbing_unit", "climbing_unit"]),
         "cables[0] (main).ends", ["connects a body", "two anchors"]),
    Case("cable with both ends on one body", _set("cables", 1, "ends", value=["CC.a1", "CC.top"]),
         "cables[1] (L1).ends", ["two different bodies", "both ends on body 'CC'"]),
    Case("cable with both length and winch", _set("cables", 1, "length", value=0.7), "cables[1] (L1)",
         ["exactly one of 'length'", "'winch'", "found both"]),
    Case("cable with neither length nor winch", _pop("cables", 0, "length"), "cables[0] (main)",
         ["exactly one of 'length'", "'winch'", "found neither"]),
    Case("actuator on an undefined body", _set("actuators", 3, "body", value="XX"), "actuators[3] (yaw_torque).body",
         ["defined body", "'CC', 'SU'", "found 'XX'"]),
    Case("winch tension on a cable without a winch", _set("actuators", 0, "cable", value="main"),
         "actuators[0] (tension_1).cable",
         ["cable with a winch", "'L1', 'L2', 'L3'", "found 'main'", "without a winch"]),
    Case("winch tension on an undefined cable", _set("actuators", 0, "cable", value="L9"),
         "actuators[0] (tension_1).cable", ["cable with a winch", "found 'L9'", "not a defined cable"]),
    Case("two winch tensions on one cable", _set("actuators", 1, "cable", value="L1"),
         "actuators[1] (tension_2).cable", ["one winch_tension actuator per cable", "'L1'", "actuators[0]"]),
    Case("unknown actuator kind", _set("actuators", 0, "kind", value="rocket"), "actuators[0] (tension_1).kind",
         ["'winch_tension', 'body_torque', 'body_thrust'", "found 'rocket'"]),
    Case("actuator without kind", _pop("actuators", 4, "kind"), "actuators[4] (thrust_u).kind",
         ["required", "'winch_tension', 'body_torque', 'body_thrust'", "missing"]),
    Case("actuator field of another kind", _set("actuators", 0, "axis", value="w"), "actuators[0] (tension_1).axis",
         ["unknown key 'axis'", "cable"]),
    Case("bad actuator axis", _set("actuators", 3, "axis", value="z"), "actuators[3] (yaw_torque).axis",
         ["'u', 'v' or 'w'", "found 'z'"]),
    Case("duplicate body name", _append("bodies", 1), "bodies[2].name",
         ["unique body or anchor name", "'SU' again", "bodies[1].name"]),
    Case("body named like an anchor", _set("bodies", 0, "name", value="climbing_unit"), "anchors[0].name",
         ["unique body or anchor name", "'climbing_unit' again", "bodies[0].name"], only=False),
    Case("duplicate cable name", _append("cables", 3), "cables[4].name",
         ["unique cable name", "'L3' again", "cables[3].name"]),
    Case("duplicate actuator name", _append("actuators", 5), "actuators[6].name",
         ["unique actuator name", "'thrust_v' again", "actuators[5].name"]),
    # --- task ---
    Case("task on an undefined body", _set("task", 1, "body", value="XX"), "task[1] (yaw).body",
         ["defined body", "found 'XX'"]),
    Case("task without a position constraint", lambda d: d.update(task=d["task"][1:]), "task",
         ["exactly one servo-constraint of kind 'position'", "found 0", "yaw, level"]),
    Case("task with two position constraints", lambda d: d["task"].append({"kind": "position", "body": "CC"}), "task",
         ["exactly one servo-constraint of kind 'position'", "found 2"]),
    Case("unknown task kind", _set("task", 0, "kind", value="pose"), "task[0].kind",
         ["'position', 'yaw', 'level'", "found 'pose'"]),
    Case("empty task", _set("task", value=[]), "task", ["at least 1 item", "found 0"]),
    # --- controller ---
    Case("bad recovery name", _set("controller", "penalty", "recovery", value="eq99"), "controller.penalty.recovery",
         [*(f"'{r}'" for r in RECOVERIES), "found 'eq99'"]),
    Case("kappa above 1", _set("controller", "penalty", "kappa", value=2.0), "controller.penalty.kappa",
         ["expected 0 <= kappa <= 1", "found 2"]),
    Case("path that does not move", _set("path", "waypoints", value=[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]),
         "path.waypoints", ["at least two distinct waypoints", "yaw-only", "found 2 equal"]),
    Case("zero actuator gain", _set("actuators", 0, "gain", value=0.0), "actuators[0] (tension_1).gain",
         ["expected 0.001 <= |gain| <= 1000", "found 0"]),
    Case("limits in the wrong order", _set("actuators", 1, "limits", value=[10.0, 5.0]),
         "actuators[1] (tension_2).limits", ["min < max", "min = 10", "max = 5"]),
    Case("non-numeric limit", _set("actuators", 0, "limits", value=[0.0, "lots"]),
         "actuators[0] (tension_1).limits[1]", ["expected a number", "'lots'"]),
    Case("NaN limit", _set("actuators", 3, "limits", value=[float("nan"), 1.0]),
         "actuators[3] (yaw_torque).limits[0]", ["-1e9 <= limit <= 1e9 or ±inf", "found nan"]),
    Case("one limit", _set("actuators", 4, "limits", value=[1.0]),
         "actuators[4] (thrust_u).limits", ["2 numbers [min, max]", "1 item"]),
    Case("winch limits that push", _set("actuators", 2, "limits", value=[-5.0, 300.0]),
         "actuators[2] (tension_3).limits", ["never make the cable push", "min >= 0", "[-5, 300]"]),
    Case("upper limit of -inf", _set("actuators", 5, "limits", value=[float("-inf"), float("-inf")]),
         "actuators[5] (thrust_v).limits", ["min < max"]),
    Case("preferred outside the limits", _set("actuators", 0, "preferred", value=-1.0),
         "actuators[0] (tension_1).preferred", ["within the limits [0, inf]", "found -1"]),
]


def _problems(mutate) -> list[tuple[str, str]]:
    data = raw_spec("acroboter")
    mutate(data)
    with pytest.raises(SpecError) as info:
        parse_spec(data, "mutated.toml")
    return info.value.problems


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_malformed_spec_names_path_expected_and_found(case: Case):
    problems = _problems(case.mutate)
    at_path = [msg for path, msg in problems if path == case.path]
    assert at_path, f"no problem reported at {case.path!r}; got {problems}"
    assert any(all(w in msg for w in case.words) for msg in at_path), f"{case.words} not all in {at_path}"
    assert all(msg.startswith("expected") and "found" in msg for _, msg in problems), problems
    if case.only:
        assert len(problems) == 1, f"expected one problem, got {problems}"


def test_each_case_has_its_own_message():
    messages = [_problems(c.mutate) for c in CASES]
    texts = [str(sorted(m)) for m in messages]
    assert len(set(texts)) == len(texts)


def test_every_problem_is_reported_at_once():
    problems = _problems(
        _both(_set("bodies", 1, "mass", value=-1.0), _set("bodies", 0, "colour", value="red"),
              _pop("controller", "kp"))
    )
    assert {p for p, _ in problems} == {"bodies[1].mass", "bodies[0].colour", "controller.kp"}


def test_error_text_lists_source_and_problems():
    data = raw_spec("acroboter")
    data["bodies"][1]["mass"] = "heavy"
    with pytest.raises(SpecError) as info:
        parse_spec(data, "crane.toml")
    text = str(info.value)
    assert text.splitlines()[0] == "invalid model spec crane.toml:"
    assert "  bodies[1].mass: expected a number, found 'heavy' (a string)" in text.splitlines()


@pytest.mark.parametrize("path", SHIPPED_SPECS, ids=[p.stem for p in SHIPPED_SPECS])
def test_shipped_specs_validate(path):
    spec = load_spec(path)
    assert spec.name == path.stem
    # the validated spec round-trips through its own dump (polar points come back as tables)
    assert parse_spec(spec.model_dump(mode="json")) == spec


def test_integers_are_accepted_for_floats():
    data = raw_spec("acroboter")
    data["bodies"][0]["mass"] = 10
    assert parse_spec(data).bodies[0].mass == 10.0


# --- files and the command line -------------------------------------------------------------------


def test_missing_file(tmp_path):
    with pytest.raises(SpecError) as info:
        load_spec(tmp_path / "nope.toml")
    assert info.value.problems == [("(file)", "expected a readable TOML file, found nothing at this path")]


def test_toml_syntax_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nmass = = 3\n')
    with pytest.raises(SpecError) as info:
        load_spec(bad)
    [(path, msg)] = info.value.problems
    assert path == "(syntax)" and "expected valid TOML" in msg and "line 2" in msg


def _bad_spec_file(tmp_path):
    text = (REPO / "model_spec" / "acroboter.toml").read_text()
    assert text.count("mass = 8.0") == 1
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("mass = 8.0", 'mass = "heavy"'))
    return bad


def _run_cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "acroboter", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("command", ["generate", "check"])
def test_cli_reports_a_bad_spec_without_traceback(tmp_path, command):
    bad = _bad_spec_file(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    result = _run_cli(command, bad, "--out", out)
    assert result.returncode == 2, result
    assert "Traceback" not in result.stderr + result.stdout
    assert f"invalid model spec {bad}" in result.stderr
    assert "bodies[1].mass: expected a number, found 'heavy' (a string)" in result.stderr
    assert list(out.iterdir()) == []  # nothing generated


def test_cli_reports_undefined_reference(tmp_path):
    data_text = (REPO / "model_spec" / "acroboter.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(data_text.replace('ends = ["CC.a1", "SU.b1"]', 'ends = ["CC.a9", "SU.b1"]'))
    result = _run_cli("generate", bad, "--out", tmp_path / "out")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "cables[1] (L1).ends[0]: expected a point of body 'CC'" in result.stderr


@pytest.mark.parametrize(
    "content, words",
    [(None, ["(file)", "found nothing"]), ('name = "x"\nmass = = 3\n', ["(syntax)", "expected valid TOML"])],
    ids=["missing file", "TOML syntax error"],
)
def test_cli_reports_unreadable_spec(tmp_path, content, words):
    spec = tmp_path / "spec.toml"
    if content is not None:
        spec.write_text(content)
    result = _run_cli("generate", spec, "--out", tmp_path / "out")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr + result.stdout
    assert all(w in result.stderr for w in words), result.stderr


def test_cli_refuses_two_specs_with_one_name(tmp_path):
    """Both would write generated/<name>/: the second is an error, and nothing is written."""
    copy = tmp_path / "copy.toml"
    copy.write_text((REPO / "model_spec" / "acroboter.toml").read_text().replace("mass = 8.0", "mass = 8.5"))
    out = tmp_path / "out"
    result = _run_cli("generate", REPO / "model_spec" / "acroboter.toml", copy, "--out", out)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "expected a name of its own, found 'acroboter'" in result.stderr
    assert not out.exists() or list(out.iterdir()) == []


def test_limits_default_by_actuator_kind_and_gain():
    """Winches pull (tension gain·u >= 0), thrusts and torques are unbounded unless the spec says."""
    data = raw_spec("acroboter")
    data["actuators"][1]["gain"] = -1.0  # reversed mounting: pulling is u <= 0
    data["actuators"][4]["limits"] = [-2.0, float("inf")]
    data["actuators"][5]["preferred"] = 0.5
    low, high, preferred = parse_spec(data).input_limits()
    inf = float("inf")
    assert low.tolist() == [0.0, -inf, 0.0, -inf, -2.0, -inf]
    assert high.tolist() == [inf, 0.0, inf, inf, inf, inf]
    assert preferred.tolist() == [0.0, 0.0, 0.0, 0.0, -2.0, 0.5]


def test_limits_do_not_change_the_generated_code():
    """Limits are read at run time: editing them keeps the spec's model hash (no regeneration)."""
    data = raw_spec("acroboter")
    before = parse_spec(data).model_hash()
    data["actuators"][0]["limits"] = [5.0, 300.0]
    data["actuators"][0]["preferred"] = 20.0
    assert parse_spec(data).model_hash() == before

