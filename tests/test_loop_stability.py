"""Why a loop diverges (acroboter.sim.loop_stability): its two linearisations against what the closed loop itself
does (the plant is the oracle).

- The paper's crane: both stable, for MLM and the penalty methods; its runs track the path.
- The four-input crane: its zero dynamics grow (MLM diverges at 28.9 s, docs/studies.md); a diverged run's
  message names the cause.
- crane_2 (generated): the continuous motion is stable, the 50 Hz loop is not (a 4 Hz mode): its run diverges at
  25 s and says so; the same crane at 100 Hz grows four times slower and tracks the whole path.
- crane_219 (generated): zero dynamics growing at ~8.8 1/s; the run diverges within 5 s, for every method.
"""

from __future__ import annotations

import numpy as np
import pytest

from acroboter.api.crane import Crane
from acroboter.model.crane_generator import RandomDraw, crane_spec, generated_crane
from acroboter.model.spec import parse_spec
from acroboter.sim.loop_stability import UNSTABLE_GROWTH, loop_stability


def at_start(crane: Crane, method: str):
    return loop_stability(crane.model, crane.path, crane.gains(), method, crane.equilibrium().q,
                          np.zeros(crane.layout.n), 0.0)


@pytest.mark.parametrize("method", ["mlm", "penalty", "iterative-3"])
def test_the_paper_crane_is_stable_in_both_senses(method):
    stability = at_start(Crane.from_example("acroboter"), method)
    assert stability.zero_dynamics_growth < 0 and stability.sampled_growth < 0
    assert stability.cause is None and stability.describe() is None


def test_the_four_input_crane_s_zero_dynamics_grow_and_its_run_says_so():
    crane = Crane.from_example("acroboter_4input")
    for method in ("mlm", "penalty"):
        stability = at_start(crane, method)
        assert stability.cause == "zero dynamics", stability
        assert 0.03 < stability.zero_dynamics_growth < 0.3  # slow: the run lasts 28.9 s
    result = crane.simulate("mlm")
    assert result.diverged_at is not None and 20.0 < result.diverged_at < 40.0
    assert result.run.divergence.startswith("the crane's zero dynamics are unstable at t = 0.00 s")


def _crane_2(rate_hz: float) -> Crane:
    data = generated_crane(RandomDraw(2), f"crane_2_at_{rate_hz:g}_hz")
    assert {**data, "name": "crane_2"} == generated_crane(RandomDraw(2), "crane_2")  # the fuzz's crane_2 but its name
    data["controller"]["rate_hz"] = rate_hz
    return Crane.from_spec(parse_spec(data, "crane_2.toml"))


def test_a_loop_the_hold_destabilises_is_named_and_a_faster_rate_holds_it():
    slow, fast = _crane_2(50.0), _crane_2(100.0)
    s50, s100 = at_start(slow, "mlm"), at_start(fast, "mlm")
    assert s50.zero_dynamics_growth < 0 and s50.cause == "sampled loop"
    assert 2.0 < s50.sampled_hz < 6.0
    assert s100.sampled_growth < s50.sampled_growth / 3
    run50, run100 = slow.simulate("mlm"), fast.simulate("mlm")
    assert run50.diverged_at is not None and run50.run.divergence.startswith("the sampled loop is unstable")
    assert run100.diverged_at is None and float(np.max(run100.position_error_mm)) < 0.1


def test_fast_zero_dynamics_end_every_exact_method_early():
    crane = Crane.from_spec(crane_spec(219))
    stability = at_start(crane, "mlm")
    assert stability.cause == "zero dynamics" and stability.zero_dynamics_growth > 5.0
    assert stability.zero_dynamics_growth > 100 * UNSTABLE_GROWTH
    for method in ("mlm", "penalty"):
        result = crane.simulate(method)
        assert result.diverged_at is not None and result.diverged_at < 6.0
        assert "zero dynamics are unstable" in result.run.divergence
