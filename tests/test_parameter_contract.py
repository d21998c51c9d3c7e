"""Issue 35: the controller's parameters are declared once (acroboter.model.controller_parameters) and the spec's
schema, the settings, the generated C's parameter layout, the command lines' options, the library's overrides and
every validation are derived from that declaration.

The strongest check is the last: a copy of the package with one added declaration line, and nothing else
edited, has the new gain in the spec, the C's layout, `run` and `export-step`, `Crane.gains` and the messages.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest
from conftest import REPO

from acroboter.model.controller_parameters import (
    OVERRIDES,
    PARAMETERS,
    RUNTIME_NAMES,
    runtime_names,
    runtime_vector,
    runtime_view,
)
from acroboter.model.schema import Controller
from acroboter.model.settings import Gains, resolve_gains
from acroboter.model.spec import load_spec
from acroboter.process.locations import example_spec


def test_each_parameter_is_a_spec_field_with_its_range_and_default():
    spec = load_spec(example_spec("acroboter"))
    for item in PARAMETERS:
        table = Controller
        parts = item.spec_field.split(".")[1:]
        for part in parts[:-1]:
            table = table.model_fields[part].annotation
        field = table.model_fields[parts[-1]]
        if item.range is not None:
            assert item.range in field.metadata, item.name
        assert item.read(spec) == getattr(Gains.from_spec(spec), item.name)


def test_the_generated_layout_is_the_declared_one():
    """Every shipped spec's manifest lists p as the declaration orders it: the C reads what Python writes."""
    for manifest in sorted((REPO / "generated").glob("*/manifest.json")):
        layout = json.loads(manifest.read_text())["layout"]
        assert layout["parameters"] == runtime_names(layout["servo_constraints"]), manifest


def test_the_vector_round_trips_by_name():
    gains = Gains.from_spec(load_spec(example_spec("acroboter")), kp=7.0, mu=0.7, ki=3.0)
    p = runtime_vector(gains, 3)
    view = runtime_view(p, 3)
    assert {name: getattr(view, name) for name in RUNTIME_NAMES} == {n: getattr(gains, n) for n in RUNTIME_NAMES}
    assert list(view.z) == [0.0, 0.0, 0.0]
    assert len(p) == len(RUNTIME_NAMES) + 3


def test_every_option_of_run_and_export_step_is_a_declared_parameter(capsys):
    from acroboter.cli.generate import export_step_main
    from acroboter.cli.run_args import parse_args

    for argv, main in ((["run"], parse_args), (["export-step"], export_step_main)):
        with pytest.raises(SystemExit):
            main(["--help"])
        text = capsys.readouterr().out
        for item in PARAMETERS:
            wanted = item.option and (item.exported or argv == ["run"])
            assert (f"{item.flag} " in text or f"{item.flag}\n" in text) == wanted, (argv, item.flag)


@pytest.mark.parametrize("name", [name for name in OVERRIDES if name not in ("recovery", "saturation")])
def test_an_override_outside_its_range_names_itself(name):
    spec = load_spec(example_spec("acroboter"))
    item = next(p for p in PARAMETERS if p.name == name)
    with pytest.raises(ValueError, match=rf"^{name}: expected "):
        resolve_gains(spec, **{name: (item.range.high or 1.0) * 10.0 + 1.0})
    with pytest.raises(TypeError, match="unknown controller setting"):
        resolve_gains(spec, not_a_gain=1.0)


DUMMY = ('    ControllerParameter("dummy_gain", "controller", "a gain a test declares", '
         'Range("dummy_gain", 0.0, 10.0, "1/s"), default=1.0, runtime=True),\n')

CHECKS = textwrap.dedent('''
    import json, sys, tomllib, types
    from pathlib import Path
    import acroboter
    assert Path(acroboter.__file__).resolve().is_relative_to(Path(sys.argv[1]).resolve()), acroboter.__file__
    from acroboter.api.crane import Crane
    from acroboter.codegen.emit_c import GenerationContext
    from acroboter.model.spec import SpecError, load_spec, parse_spec
    spec_path, raw = Path(sys.argv[2]), Path(sys.argv[2]).read_text()
    report = {}
    spec = load_spec(spec_path)
    # the spec: a field of [controller] with its default, and its value when given
    def given(value):
        return tomllib.loads(raw.replace("[controller]\\n", f"[controller]\\ndummy_gain = {value}\\n", 1))
    with_value = parse_spec(given(3.0), "dummy.toml")
    report["spec_default"] = spec.controller.dummy_gain
    report["spec_value"] = with_value.controller.dummy_gain
    try:
        parse_spec(given(30.0), "dummy.toml")
    except SpecError as err:
        report["spec_error"] = str(err)
    # the C: the manifest's layout and the generated solver terms' p
    context = GenerationContext(spec)
    context.register_solver_terms("penalty_terms", __import__("acroboter.codegen.solver_terms",
                                                              fromlist=["penalty_terms"]).penalty_terms)
    k = context.model.layout.k
    report["c_parameters"] = context.manifest()["layout"]["parameters"]
    report["c_p_size"] = context.functions["penalty_terms"].numel_in(5)
    report["k"] = k
    # the API: Crane.gains (what every run calls) and the settings' vector
    crane = types.SimpleNamespace(spec=spec)
    gains = Crane.gains(crane, dummy_gain=2.0)
    report["api_value"] = gains.dummy_gain
    report["vector"] = list(gains.parameter_vector(k))
    try:
        Crane.gains(crane, dummy_gain=20.0)
    except ValueError as err:
        report["api_error"] = str(err)
    print(json.dumps(report))
''')


def test_a_parameter_declared_in_one_place_reaches_the_spec_the_c_the_cli_the_api_and_the_checks(tmp_path):
    """One line added to PARAMETERS in a copy of the package; nothing else edited."""
    package = tmp_path / "copy" / "acroboter"
    shutil.copytree(REPO / "acroboter", package, ignore=shutil.ignore_patterns("__pycache__"))
    for shared in ("model_spec", "generated", "pyproject.toml"):  # a checkout: its examples found as in this one
        (tmp_path / "copy" / shared).symlink_to(REPO / shared)
    declaration = package / "model" / "controller_parameters.py"
    text = declaration.read_text()
    anchor = '    ControllerParameter("recovery",'
    assert text.count(anchor) == 1
    declaration.write_text(text.replace(anchor, DUMMY + anchor))
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "copy"), "ACROBOTER_CACHE_DIR": str(tmp_path / "cache")}
    spec = example_spec("acroboter")

    def run(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, *argv], capture_output=True, text=True, env=env, cwd=tmp_path,
                              timeout=600)

    checks = run("-c", CHECKS, str(tmp_path / "copy"), str(spec))
    assert checks.returncode == 0, checks.stderr
    report = json.loads(checks.stdout.strip().splitlines()[-1])
    assert report["spec_default"] == 1.0 and report["spec_value"] == 3.0
    assert "controller.dummy_gain: expected 0 <= dummy_gain <= 10 (1/s), found 30" in report["spec_error"]
    slot = len(RUNTIME_NAMES)  # after every existing slot: the existing ones keep their places
    assert report["c_parameters"][:slot] == list(RUNTIME_NAMES)
    assert report["c_parameters"][slot] == "dummy_gain"
    assert report["c_p_size"] == slot + 1 + report["k"]
    assert report["api_value"] == 2.0 and report["vector"][slot] == 2.0
    assert report["api_error"].startswith("dummy_gain: expected 0 <= dummy_gain <= 10 (1/s), found 20")
    for command in ("run", "export-step"):
        shown = run("-m", "acroboter", command, "--help")
        assert shown.returncode == 0, shown.stderr
        assert "--dummy-gain DUMMY_GAIN" in shown.stdout and "a gain a test declares" in shown.stdout
    refused = run("-m", "acroboter", "run", "--dummy-gain", "20", "--out", str(tmp_path / "out"))
    assert refused.returncode == 2
    assert "--dummy-gain: expected 0 <= dummy_gain <= 10 (1/s), found 20" in refused.stderr
    assert not (tmp_path / "out").exists()
