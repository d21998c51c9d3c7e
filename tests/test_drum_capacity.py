"""One cable model: a winch's drum holds `winch.capacity` metres of cable (acroboter.model.physical.drum_capacities),
and the own plant, the MuJoCo plant and the MJCF all take it from there: a run that pays a cable out to it stops in
both plants, with the same words, at the same time."""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import raw_spec

from acroboter.api.crane import Crane
from acroboter.model.layout import build_layout, nominal_coordinates
from acroboter.model.mjcf_model import mjcf_xml, routing_tendon
from acroboter.model.physical import DRUM_RESERVE_M, drum_capacities
from acroboter.model.spec import parse_spec

PAY_OUT_M = 0.05  # the capacity: L1's nominal length and this much more


def _spec(extra: float = PAY_OUT_M):
    data = copy.deepcopy(raw_spec("acroboter"))
    spec = parse_spec(data, "acroboter.toml")
    layout = build_layout(spec)
    start = float(nominal_coordinates(spec, layout)[layout.winch_index["L1"]])
    data["name"] = "acroboter_short_drum"
    next(c for c in data["cables"] if c["name"] == "L1")["winch"]["capacity"] = round(start + extra, 6)
    return parse_spec(data, "short_drum.toml"), start


def test_the_capacity_is_the_specs_or_the_nominal_length_and_the_reserve():
    spec, start = _spec()
    capacity = drum_capacities(spec)
    assert capacity["L1"] == pytest.approx(start + PAY_OUT_M, abs=1e-6)
    assert capacity["L2"] == pytest.approx(start + DRUM_RESERVE_M, abs=1e-9)  # the symmetric crane: the same start
    root = ET.fromstring(mjcf_xml(spec))  # the MJCF's drum ends there
    ranges = {t.get("name"): [float(v) for v in t.get("range").split()] for t in root.iter("spatial")
              if t.get("range")}
    assert ranges[routing_tendon("L1")][1] == pytest.approx(capacity["L1"], abs=1e-9)
    assert ranges[routing_tendon("L2")][1] == pytest.approx(capacity["L2"], abs=1e-9)


def test_a_drum_shorter_than_its_cable_is_refused_before_any_work():
    from acroboter.model.mjcf_model import MjcfError

    spec, start = _spec(extra=-0.01)
    with pytest.raises(MjcfError, match=r"cables\[1\] \(L1\)\.winch\.capacity: expected more than the cable's length"):
        mjcf_xml(spec)
    with pytest.raises(MjcfError, match=r"winch\.capacity"):
        Crane.from_spec(spec)


def test_both_plants_stop_where_a_cable_is_paid_out_to_its_drums_end():
    """L1's winch lets go (its input pays the cable out): the unit drops on that side until L1 reaches its drum's end,
    5 cm further. Both plants stop there, within a plant step of each other, with the same message."""
    pytest.importorskip("mujoco")
    spec, start = _spec()
    crane = Crane.from_spec(spec)
    static = crane.equilibrium().inputs.copy()
    let_go = static.copy()
    let_go[0] = -5.0  # N: the drum pays out under the cable's pull and this

    def inputs(t):
        return static if t < 0.1 else let_go

    runs = {plant: crane.simulate_open_loop(inputs, 2.0, plant=plant) for plant in ("own", "mujoco")}
    for plant, run in runs.items():
        assert run.diverged_at is not None, f"{plant}: the run went on past the drum's end"
        assert "cable L1 is paid out to" in run.run.divergence and "winch.capacity" in run.run.divergence, plant
        paid = run.coordinate("L1.length")[-1]
        assert paid <= start + PAY_OUT_M + 1e-6, plant
    own, engine = runs["own"].diverged_at, runs["mujoco"].diverged_at
    assert abs(own - engine) <= 2 * spec.simulation.step + 1e-12, (own, engine)
    # up to there the two plants flew alike (the unit's centre)
    steps = min(len(runs["own"].time), len(runs["mujoco"].time))
    b = crane.layout.body_offset["SU"]
    assert np.abs(runs["own"].q[:steps, b : b + 3] - runs["mujoco"].q[:steps, b : b + 3]).max() < 1e-4
