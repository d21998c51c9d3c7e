"""A range for every number (acroboter.model.ranges): every numeric field of the spec's schema and every numeric
option of every command has one, found by walking the schema and the commands' parsers, so that a new number
without a range fails here. Each is tried with 0, −0, tiny, huge, ±inf and NaN: inside its range it is taken,
outside it is refused before any work with '<field or option>: expected <range>, found <value>' (exit 2 for an
option), never a traceback or a library's message. docs/spec.md and docs/errors.md show every range.

The walks call only the validation (parse_spec, an option's type, a command's argument parsing, in-process): each
case takes milliseconds. The issue's own cases (issue 24) run through the commands at the end.
"""

from __future__ import annotations

import argparse
import copy
import importlib
import math
import re
import subprocess
import sys
import types
from pathlib import Path
from typing import Annotated, Any, Union, get_args, get_origin
from unittest import mock

import pytest
from conftest import REPO, raw_spec
from pydantic import BaseModel

from acroboter.cli.console import COMMANDS
from acroboter.model import ranges
from acroboter.model.controller_parameters import PARAMETERS, parameter
from acroboter.model.ranges import Range
from acroboter.model.spec import Spec, SpecError, parse_spec
from acroboter.model.spec_errors import _format_loc

FLOATS = [0.0, -0.0, 1e-300, 1e300, math.inf, -math.inf, math.nan]
WHOLES = [0, -0, 1, 10**30, math.inf, -math.inf, math.nan, 0.5]  # a whole number's tiny is 1; a float is refused
TEXTS = ["0", "-0", "1e-300", "1e300", "inf", "-inf", "nan"]


# --- the spec's fields ----------------------------------------------------------------------------------------


def _range_of(metadata) -> Range | None:
    return next((m for m in metadata if isinstance(m, Range)), None)


def _numeric_leaves(tp, found: Range | None = None):
    """(Range or None, is_numeric) for each leaf of a field's type; the nearest Annotated's Range counts."""
    origin = get_origin(tp)
    if origin is Annotated:
        inner, *metadata = get_args(tp)
        yield from _numeric_leaves(inner, _range_of(metadata) or found)
    elif origin in (Union, types.UnionType, list, dict, tuple):
        for arg in get_args(tp):
            yield from _numeric_leaves(arg, found if origin in (Union, types.UnionType) else None)
    elif isinstance(tp, type) and issubclass(tp, BaseModel):
        return  # a table of its own: walked as a model
    elif tp in (int, float):
        yield found


def _models(model: type[BaseModel], seen: set) -> None:
    if model in seen:
        return
    seen.add(model)
    for field in model.model_fields.values():
        for tp in _all_types(field.annotation):
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                _models(tp, seen)


def _all_types(tp):
    yield tp
    for arg in get_args(tp):
        yield from _all_types(arg)


def _defining(model: type[BaseModel], name: str) -> type:
    return next(k for k in reversed(model.__mro__) if name in getattr(k, "__annotations__", {}))


def schema_numeric_fields() -> dict[tuple[str, str], list[Range | None]]:
    """(defining class, field) -> the Ranges of its numeric leaves, for every table of the schema."""
    models: set = set()
    _models(Spec, models)
    fields = {}
    for model in models:
        for name, field in model.model_fields.items():
            leaves = list(_numeric_leaves(Annotated[(field.annotation, *field.metadata)] if field.metadata
                                          else field.annotation))
            if leaves:
                fields[(_defining(model, name).__name__, name)] = leaves
    return fields


def full_spec() -> dict:
    """The default crane with every optional numeric field present (limits, preferred, points, sensing, ...)."""
    data = raw_spec("acroboter")
    data["bodies"][0]["initial_yaw_deg"] = 0.0
    data["actuators"][0].update(limits=[0.0, 100.0], preferred=10.0, gain=1.0)
    data["actuators"][4]["point"] = [0.0, 0.0, 0.0]
    data["task"][0]["point"] = [0.0, 0.0, 0.0]
    data["cables"][1]["winch"]["capacity"] = 5.0
    data["controller"]["ki"] = 0.0
    data["controller"]["underactuation"] = {"dwell": 0.1, "margin": 0.001}
    data["sensing"] = {"groups": [{"name": "positions", "coordinates": ["SU.r"], "noise": 0.0, "quantization": 1e-4}],
                       "delay_periods": 0, "seed": 0, "velocity_filter_s": 0.02, "projection_iterations": 3}
    return data


def _first_number(value, path: tuple) -> tuple | None:
    """The data path of the first number in a field's value (not inside a table of its own)."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return path
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        if (found := _first_number(item, (*path, key))) is not None:
            return found
    return None


def _tables_in(value, path: tuple):
    if isinstance(value, BaseModel):
        yield path, value
        return
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        yield from _tables_in(item, (*path, key))


def instance_leaves(node: BaseModel, path: tuple = (), out=None, seen=None) -> list:
    """(data path, Range, (defining class, field)): the first number of each numeric field of each table of a
    validated spec, once per field (the tables of every list item are walked: an actuator of each kind)."""
    out, seen = ([], set()) if out is None else (out, seen)
    for name, field in type(node).model_fields.items():
        value = getattr(node, name)
        if value is None:
            continue
        key = (_defining(type(node), name).__name__, name)
        tp = Annotated[(field.annotation, *field.metadata)] if field.metadata else field.annotation
        if key not in seen and (first := _first_number(value, (*path, name))) is not None:
            seen.add(key)
            rng = next((r for t in _all_types(tp) if get_origin(t) is Annotated
                        and (r := _range_of(get_args(t)[1:])) is not None), None)
            out.append((first, rng, key))
        for sub_path, table in _tables_in(value, (*path, name)):
            instance_leaves(table, sub_path, out, seen)
    return out


FULL = full_spec()
LEAVES = instance_leaves(parse_spec(FULL, "full.toml"))


def _set(data: dict, path: tuple, value) -> None:
    node = data
    for part in path[:-1]:
        node = node[part]
    node[path[-1]] = value


def test_every_numeric_spec_field_has_a_range():
    fields = schema_numeric_fields()
    without = sorted(f"{cls}.{name}" for (cls, name), leaves in fields.items() if any(r is None for r in leaves))
    assert not without, f"numeric spec fields without a Range (acroboter.model.ranges): {without}"
    tried = {key for _, _, key in LEAVES}
    assert set(fields) <= tried, f"numeric fields the full spec of this test lacks: {sorted(set(fields) - tried)}"


@pytest.mark.parametrize("path, range_", [(p, r) for p, r, _ in LEAVES],
                         ids=[_format_loc(list(p)) for p, _, _ in LEAVES])
def test_a_spec_number_outside_its_range_is_refused_naming_field_and_range(path, range_):
    where = _format_loc(list(path), FULL)
    for value in (WHOLES if range_.whole else FLOATS):
        data = copy.deepcopy(FULL)
        _set(data, path, value)
        try:
            parse_spec(data, "x.toml")
        except SpecError as err:
            # the number's own path, or its field's (a check of the whole tensor, of [min, max])
            mine = [msg for loc, msg in err.problems if loc == where or where.startswith(loc + "[")]
            assert mine, f"{where} = {value!r} refused without naming it: {err.problems}"
            if not range_.contains(value):
                assert any(f"expected {range_.text()}, found" in msg for msg in mine), (where, value, mine)
        else:
            assert range_.contains(value), f"{where} = {value!r} is outside {range_.text()} but was accepted"


def test_the_spec_ranges_are_documented():
    text = (REPO / "docs" / "spec.md").read_text().replace("\\|", "|")  # a table cell escapes |gain|
    missing = sorted({r.text() for _, r, _ in LEAVES if r.text() not in text})
    assert not missing, f"docs/spec.md does not show these ranges: {missing}"


# --- the commands' options ------------------------------------------------------------------------------------


class _Captured(BaseException):  # not an Exception: the commands' error boundary lets it through
    def __init__(self, parser):
        self.parser = parser


def command_parser(name: str) -> tuple[argparse.ArgumentParser, Any, tuple]:
    module, func, prefix = COMMANDS[name]
    main = getattr(importlib.import_module(module), func)

    def capture(self, *args, **kwargs):
        raise _Captured(self)

    with mock.patch.object(argparse.ArgumentParser, "parse_args", capture), \
            mock.patch.object(argparse.ArgumentParser, "parse_intermixed_args", capture):
        try:
            main([*prefix])
        except _Captured as got:
            return got.parser, main, prefix
    raise AssertionError(f"{name} parsed no arguments")


PARSERS = {name: command_parser(name) for name in COMMANDS}
# Options that take text, not a number (a path, a name, a method whose N is checked as its own number).
TEXT_OPTIONS = {"spec", "specs", "out", "cache_dir", "limits_spec", "results", "method", "methods", "scheduler",
                "gif", "command", "which", "path", "trajectory", "certify"}


def numeric_options() -> tuple[list, list[str]]:
    """(command, action) of every option typed with a range; and the options that are neither that nor text."""
    ranged, unranged = [], []
    for name, (parser, _, _) in PARSERS.items():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction | argparse._VersionAction) or action.nargs == 0:
                continue
            if action.choices is not None:
                continue
            if hasattr(action.type, "ranges"):
                ranged.append((name, action))
            elif action.dest not in TEXT_OPTIONS:
                unranged.append(f"acroboter {name} {'/'.join(action.option_strings) or action.dest}")
    return ranged, unranged


OPTIONS, UNRANGED = numeric_options()


def test_every_numeric_option_has_a_range():
    assert not UNRANGED, (f"options without a range: {UNRANGED}: type them with acroboter.cli.entry.ranged (or name "
                          "them in TEXT_OPTIONS if they take no number)")


def test_every_command_is_walked_and_has_its_numbers():
    assert {"run", "sweep", "robustness", "animate", "mjcf", "export-step", "plant-fuzz", "bench", "study"} <= {
        name for name, _ in OPTIONS}
    assert len(OPTIONS) >= 50


@pytest.mark.parametrize("command, action", OPTIONS,
                         ids=[f"{c} {a.option_strings[0] if a.option_strings else a.dest}" for c, a in OPTIONS])
def test_an_option_outside_its_range_exits_2_naming_option_and_range(command, action, capsys):
    parser, main, prefix = PARSERS[command]
    option = action.option_strings[0]
    texts = [action.type.template.format(t) for t in TEXTS]
    for text in texts:
        try:
            value = action.type(text)
        except argparse.ArgumentTypeError as err:
            message = str(err)
            assert not action.type.ranges or any(r.text() in message for r in action.type.ranges), (option, message)
            with pytest.raises(SystemExit) as stop:
                main([*prefix, f"{option}={text}"])
            err_text = capsys.readouterr().err
            assert stop.value.code == 2, err_text
            assert f"argument {option}: " in err_text and message in err_text, err_text
            assert "Traceback" not in err_text and "internal error" not in err_text
            continue
        if len(action.type.ranges) == 1 and not isinstance(value, tuple):  # taken: it is in its range
            for each in value if isinstance(value, list) else [value]:
                assert action.type.ranges[0].contains(each), (option, text, value)


def test_the_option_ranges_are_documented():
    text = (REPO / "docs" / "errors.md").read_text().replace("\\|", "|")
    missing = sorted({f"{name} {a.option_strings[0]}: {r.text()}" for name, a in OPTIONS for r in a.type.ranges
                      if r.text() not in text})
    assert not missing, f"docs/errors.md does not show these ranges: {missing}"


def test_the_message_form():
    assert ranges.KP.problem(1e308) == "expected 0 < kp <= 1e4 (1/s), found 1e+308"
    with pytest.raises(ranges.RangeError, match=r"^--kp: expected 0 < kp <= 1e4 \(1/s\), found 1e\+308$"):
        ranges.KP.check(1e308, "--kp")
    assert ranges.GAIN.text() == "0.001 <= |gain| <= 1000" and ranges.GAIN.contains(-1.0)
    assert not ranges.GAIN.contains(0.0) and ranges.LIMIT.contains(-math.inf) and not ranges.LIMIT.contains(math.nan)
    assert ranges.ITERATIONS.parse("1e3") == 1000 and ranges.SEED.contains(2**63 - 1)


def test_derived_bounds_read_as_ranges():
    # the sampled servo law (Jury): 50 Hz holds kd in (kp²/200, 50)
    assert ranges.sampled_gain_problems(5.0, 5.0, 50.0) == []
    (where, text), = ranges.sampled_gain_problems(5.0, 60.0, 50.0)
    assert where == "controller.kd" and text.startswith("expected 0.125 < kd < 50 (1/s), found 60")
    assert ranges.sampled_gain_problems(5.0, 0.1, 50.0)[0][1].startswith("expected 0.125 < kd < 50")
    assert ranges.baumgarte_problem(1.0, 20.0, 0.002) is None
    assert ranges.baumgarte_problem(1.0, 2000.0, 0.002).startswith("expected 0 < baumgarte_omega <= 1300 (1/s)")
    assert ranges.mujoco_work_problem(1e-4, 0.02) is None
    assert ranges.mujoco_work_problem(1e-7, 0.02).startswith(
        "expected 2e-7 <= mujoco_timestep <= 0.01 (s), found 1e-07")
    assert ranges.delay_problem(99, 50.0, 2.0) is None
    assert ranges.delay_problem(100, 50.0, 2.0).startswith("expected a whole number 0 <= delay_periods <= 99")
    assert ranges.frames_problem(55.0, 25.0, 1.0, ranges.SPEED) is None  # the scenario: 1376 frames
    assert ranges.frames_problem(55.0, 8.0, 1e-4, ranges.GIF_SPEED, 480 * 360).startswith(
        "expected 0.0760456 <= gif_speed <= 1000")


# --- the issue's cases, through the commands --------------------------------------------------------------------


def _spec_file(tmp_path: Path, old: str, new: str) -> Path:
    text = (REPO / "model_spec" / "acroboter.toml").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("old, new, words", [
    ("kp = 5.0", "kp = 1e200", "controller.kp: expected 0 < kp <= 1e4 (1/s), found 1e+200"),
    ("mass = 8.0", "mass = 8.0\ninitial_yaw_deg = 1e20",
     "bodies[1].initial_yaw_deg: expected -360 <= initial_yaw_deg <= 360 (deg), found 1e+20"),
    ('cable = "L1"', 'cable = "L1"\ngain = 1e300',
     "actuators[0] (tension_1).gain: expected 0.001 <= |gain| <= 1000, found 1e+300"),
], ids=["kp", "initial_yaw_deg", "winch gain"])
def test_issue_spec_cases_exit_2(tmp_path, capsys, old, new, words):
    from acroboter.cli.run import main

    assert main(["--spec", str(_spec_file(tmp_path, old, new)), "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and "internal error" not in err


@pytest.mark.parametrize("module, args, words", [
    ("acroboter.run", ["--kp", "1e308"], "argument --kp: expected 0 < kp <= 1e4 (1/s), found 1e+308"),
    ("acroboter.sweep", ["--alphas", "1e308"], "argument --alphas: expected 1 <= alpha <= 1e16, found 1e+308"),
    ("acroboter.mjcf", ["--timestep", "1e-300"], "argument --timestep: expected 1e-8 <= timestep <= 0.01 (s)"),
], ids=["run --kp", "sweep --alphas", "mjcf --timestep"])
def test_issue_option_cases_exit_2_in_a_process_of_their_own(module, args, words, tmp_path):
    proc = subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=tmp_path,
                          timeout=300)
    assert proc.returncode == 2 and words in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and "DLASCL" not in proc.stderr and "internal error" not in proc.stderr


def _exits_2(main, argv, capsys, *words):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert all(w in err for w in words) and "Traceback" not in err and "internal error" not in err, err


def test_issue_run_cases_found_with_the_spec_before_the_run(tmp_path, capsys):
    from acroboter.cli.run import main

    out = ["--out", str(tmp_path / "out"), "-q"]
    _exits_2(main, ["--sensing-delay", "1000", "--duration", "2", *out], capsys,
             "--sensing-delay: expected a whole number 0 <= delay_periods <= 99 (control periods), found 1000")
    _exits_2(main, ["--kd", "60", *out], capsys, "--kd: expected 0.125 < kd < 50 (1/s), found 60")
    _exits_2(main, ["--plant-param", "SU.mass=1e308", *out], capsys,
             "bodies[1].mass: expected 1e-6 <= mass <= 1e6 (kg), found 1e+308")
    assert not (tmp_path / "out").exists()


@pytest.mark.needs_mujoco
def test_a_mujoco_step_too_fine_for_the_control_period_is_refused(tmp_path, capsys):
    from acroboter.cli.mjcf import main as mjcf
    from acroboter.cli.run import main

    with pytest.raises(SystemExit) as stop:
        main(["--plant", "mujoco", "--mujoco-timestep", "1e-9", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "expected 1e-8 <= mujoco_timestep <= 0.01 (s), found 1e-09" in err
    _exits_2(main, ["--plant", "mujoco", "--mujoco-timestep", "1e-7", "--out", str(tmp_path / "out"), "-q"], capsys,
             "--mujoco-timestep: expected 2e-7 <= mujoco_timestep <= 0.01 (s), found 1e-07",
             "at most 100,000 MuJoCo steps per control period of 0.02 s")
    _exits_2(mjcf, ["--pose", "spec", "--timestep", "1e-7", "-o", str(tmp_path / "c.xml")], capsys,
             "--timestep: expected 2e-7 <= timestep <= 0.01 (s), found 1e-07")


def test_robustness_ranges(tmp_path, capsys):
    from acroboter.cli.robustness import main

    with pytest.raises(SystemExit) as stop:
        main(["--length-range", "1e9", "--workers", "0"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "argument --length-range: expected -1000 <= length_range <= 1000 (mm)" in err
    _exits_2(main, ["--sensing-delay", "1000", "--duration", "2", "--samples", "1", "--workers", "0", "--no-plots",
                    "--out", str(tmp_path / "rob"), "-q"], capsys,
             "--sensing-delay: expected a whole number 0 <= delay_periods <= 99")


@pytest.fixture(scope="module")
def short_results(tmp_path_factory):
    from acroboter.cli.run import main

    out = tmp_path_factory.mktemp("run")
    assert main(["--method", "penalty", "--duration", "1", "--out", str(out), "--no-plots", "-q"]) == 0
    return out


def test_animation_frames_are_counted_before_any_is_drawn(short_results, tmp_path, capsys):
    from acroboter.cli.animate import main

    for option, value in (("--gif-speed", "1e-4"), ("--speed", "1e-9")):  # the issue's: below any run's range
        with pytest.raises(SystemExit):
            main([str(short_results), option, value])
        assert f"argument {option}: expected 0.001 <= {option[2:].replace('-', '_')} <= 1000 (run s per video s), " \
               f"found {float(value):g}" in capsys.readouterr().err
    # in the range, but this 1 s run at 8 fps would hold 8,001 GIF frames of 480x360: 1.4 GB
    gif = ["--no-mp4", "--gif", str(tmp_path / "a.gif"), "--renderer", "matplotlib", "-q"]
    _exits_2(main, [str(short_results), *gif, "--gif-speed", "1e-3"], capsys,
             "--gif-speed: expected 0.00138265 <= gif_speed <= 1000 (run s per video s), found 0.001",
             "8,001 frames, 1.38 GB held")
    _exits_2(main, [str(short_results), "--out", str(tmp_path / "a.mp4"), "--fps", "240", "--speed", "1e-3",
                    "--renderer", "matplotlib", "-q"], capsys, "--speed: expected 0.0012", "240,001 frames")
    assert not list(tmp_path.iterdir())


def _range_ends(err: str) -> tuple[float, float]:
    low, high = re.search(r"expected (\S+) <=? \w+ <=? ([^\s,]+)", err).groups()
    return float(low), float(high)


@pytest.mark.parametrize("option", [p.name for p in PARAMETERS if p.option and p.range is not None])
def test_every_gain_option_names_itself_with_a_range_that_is_not_empty(option, tmp_path, capsys):
    """Issue 35: `run --kp 100` blamed --kd with an empty range (50 < kd < 50). Each gain option beyond its range,
    and kp/kd beyond what the control rate samples, names the option given and a range a value can be in."""
    from acroboter.cli.run import main

    out = ["--out", str(tmp_path / "out"), "-q"]
    limit = parameter(option).range
    too_large = ["--" + option.replace("_", "-"), repr(float(limit.high) * 10.0 if limit.high else 1e300)]
    with pytest.raises(SystemExit) as stop:  # argparse's range check: exit 2 naming the option
        main([*too_large, *out])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"--{option.replace('_', '-')}: expected" in err, err
    low, high = _range_ends(err[err.index("expected") - 1 :])
    assert low < high, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("argv", "named"), [(["--kp", "100"], "--kp"), (["--kd", "60"], "--kd"),
                                             (["--kp", "20", "--kd", "1"], "--kp"), (["--kd", "0.05"], "--kd"),
                                             (["--kp", "100", "--kd", "60"], "--kd")])
def test_the_sampled_gain_check_names_the_gain_given(argv, named, tmp_path, capsys):
    from acroboter.cli.run import main

    assert main([*argv, "--out", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {named}: expected"), err
    low, high = _range_ends(err)
    assert low < high, err
    assert not (tmp_path / "out").exists()
