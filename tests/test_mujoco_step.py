"""MuJoCo's step per crane (acroboter.sim.mujoco_step): the cable accelerations it is chosen from against closed forms,
the rule's step and a forced coarse one against what MuJoCo does, and what a run's summary says of them."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from acroboter.sim.mujoco_step import (
    STEP_ERROR_BOUND_M,
    cable_accelerations,
    chosen_step,
    crane_step,
    expected_error,
)

G = 9.81


@pytest.fixture(scope="module")
def cranes():
    from acroboter.api.crane import Crane

    return {name: Crane.from_example(name) for name in ("acroboter", "lab_crane", "acroboter_4cable")}


def test_the_main_cables_acceleration_is_its_tension_over_the_connector(cranes):
    """The main cable holds the connector and, through the winch cables, the unit: T = (m_CC + m_SU) g. Pulling along
    it moves the connector alone (the winch drums let the unit go), m_eff = m_CC. A winch cable moves its drum and,
    a little, both bodies: T/I_r < T/m_eff < T (1/I_r + 1/m_CC + 1/m_SU + the bodies' turning)."""
    crane = cranes["acroboter"]
    start = crane.equilibrium()
    found = cable_accelerations(crane.model, start.q, start.multipliers)
    cc, su = crane.spec.body("CC").mass, crane.spec.body("SU").mass
    assert found["main"] == pytest.approx((cc + su) * G / cc, rel=1e-9)
    drum = crane.spec.cables[1].winch.reflected_inertia
    tension = start.inputs[0]
    assert tension / drum < found["L1"] < tension * (1 / drum + 1 / cc + 1 / su) * 1.02
    assert found["L1"] == pytest.approx(found["L2"], rel=1e-9) == pytest.approx(found["L3"], rel=1e-9)


def test_the_rule_takes_the_coarsest_step_within_the_bound_that_divides_the_plant_step():
    assert chosen_step(500.0, 0.002) == 1e-4
    # the envelope reaches the bound at 20e-6 / (0.27 h²): 7,407 m/s² at 1e-4 s
    assert chosen_step(7_000.0, 0.002) == 1e-4 and chosen_step(8_000.0, 0.002) == 5e-5
    assert chosen_step(1e6, 0.002) == 5e-6 and chosen_step(1e9, 0.002) == 5e-6  # the finest when none is within
    assert chosen_step(500.0, 0.0003) == 1e-4 and chosen_step(500.0, 0.00015) == 5e-5  # 1e-4 does not divide 0.15 ms
    for acceleration in (10.0, 551.0, 7_407.0, 3e4):
        h = chosen_step(acceleration, 0.002)
        assert expected_error(acceleration, h) <= STEP_ERROR_BOUND_M or h == 5e-6


@pytest.mark.parametrize("name", ["acroboter", "lab_crane", "acroboter_4cable"])
def test_mujoco_at_the_rules_step_agrees_and_a_forced_coarse_step_stays_within_what_is_said(cranes, name):
    """One winch ±50 % of its static tension at 2 Hz for 3 s (no cable slack): MuJoCo at the crane's step within the
    rule's bound of the own plant; at a forced 1 ms within the expected error the summary states, and off by about
    h² (the model's exponent: 2.0-2.5 measured)."""
    pytest.importorskip("mujoco")
    crane = cranes[name]
    static = np.array(crane.equilibrium().inputs, dtype=float)

    def inputs(t):
        u = static.copy()
        u[0] += 0.5 * abs(static[0]) * math.sin(2 * math.pi * 2.0 * t)
        return u

    own = crane.simulate_open_loop(inputs, 3.0)
    rule, acceleration = crane_step(crane.model, crane.equilibrium())
    errors = {}
    for h in (rule, 5e-4, 1e-3):
        engine = crane.simulate_open_loop(inputs, 3.0, plant="mujoco", mujoco_timestep=None if h == rule else h)
        assert engine.diverged_at is None and own.diverged_at is None
        errors[h] = max(float(np.linalg.norm(own.q[:, b : b + 3] - engine.q[:, b : b + 3], axis=1).max())
                        for b in crane.layout.body_offset.values())
    assert errors[rule] <= STEP_ERROR_BOUND_M
    assert errors[1e-3] <= expected_error(acceleration, 1e-3)
    assert 2.0**1.6 <= errors[1e-3] / errors[5e-4] <= 2.0**2.8


def test_a_runs_summary_says_which_step_and_how_far_off_it_is_expected_to_be(cranes):
    pytest.importorskip("mujoco")
    from acroboter.cli.run import plant_provenance

    crane = cranes["acroboter"]
    chosen = plant_provenance(argparse.Namespace(plant="mujoco", mujoco_timestep=None), crane.spec, crane)
    assert chosen["step_s"] == 1e-4 and chosen["step_chosen_by"] == "the crane's rule"
    assert chosen["expected_error_m"] <= chosen["rule_error_bound_m"]
    forced = plant_provenance(argparse.Namespace(plant="mujoco", mujoco_timestep=1e-3), crane.spec, crane)
    assert forced["step_s"] == 1e-3 and forced["step_chosen_by"] == "--mujoco-timestep"
    assert forced["expected_error_m"] == pytest.approx(100 * chosen["expected_error_m"])
