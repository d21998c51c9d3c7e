"""Numbers each valid but implausible together get a warning naming the field (not an error): a mass
in grams, a fixed cable its ends do not fit, a drum heavier than the load. The examples get none."""

from __future__ import annotations

import logging
import tomllib
from pathlib import Path

import pytest

from acroboter.model.plausibility import plausibility_warnings
from acroboter.model.spec import load_spec, parse_spec

REPO = Path(__file__).resolve().parent.parent
DEFAULT = REPO / "model_spec" / "acroboter.toml"


@pytest.mark.parametrize("path", sorted((REPO / "model_spec").glob("*.toml")), ids=lambda p: p.stem)
def test_the_examples_are_plausible(path):
    assert plausibility_warnings(load_spec(path)) == []


def _changed(change) -> list[tuple[str, str]]:
    data = tomllib.loads(DEFAULT.read_text())
    change(data)
    return plausibility_warnings(parse_spec(data, "changed"))


def test_a_mass_in_grams_is_named():
    def grams(data):
        data["bodies"][1]["mass"] = 8000.0  # the SU's 8 kg typed in grams

    assert [(field, "800 times" in why) for field, why in _changed(grams)] == [("bodies[1].mass", True)]


def test_a_fixed_cable_its_ends_do_not_fit_is_named():
    def short(data):
        main = next(c for c in data["cables"] if c.get("length") is not None)
        main["length"] *= 0.8

    (field, why), = _changed(short)
    assert field.endswith(".length") and "apart in the bodies' initial positions" in why


def test_a_drum_heavier_than_the_load_is_named():
    def drum(data):
        data["cables"][1]["winch"]["reflected_inertia"] = 50.0  # kg·m² typed without the radius

    assert [field for field, _ in _changed(drum)] == ["cables[1].winch.reflected_inertia"]


def test_the_crane_says_it_when_built():
    from acroboter import Crane

    crane = Crane.from_example("acroboter")
    assert crane.warnings == []
    data = tomllib.loads(DEFAULT.read_text())
    data["bodies"][1]["mass"] = 8000.0
    said: list[str] = []
    handler = logging.Handler(logging.WARNING)
    handler.emit = lambda record: said.append(record.getMessage())
    logger = logging.getLogger("acroboter")  # its own handler: the console may have stopped propagation
    logger.addHandler(handler)
    try:
        heavy = Crane(parse_spec(data, "heavy"), crane.model)  # the warning comes before any model work
    finally:
        logger.removeHandler(handler)
    assert heavy.warnings and heavy.warnings[0].startswith("bodies[1].mass: 8000 kg")
    assert any("bodies[1].mass: 8000 kg" in line for line in said)
