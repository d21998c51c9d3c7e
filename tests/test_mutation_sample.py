"""`make mutation`'s small sample (docs/mutation.md): the tool runs from this checkout, mutmut judges every
mutant of one function by the distribution's oracle tests, and the report counts them. The full runs are
`make mutation` (hours on 2 cores); this keeps the pipeline from rotting between them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tools"))

import mutation  # noqa: E402
import mutation_report  # noqa: E402


def test_every_mutant_of_within_limits_is_killed(tmp_path):
    work = tmp_path / "mutation"
    done = subprocess.run(
        [sys.executable, str(REPO / "tools" / "mutation.py"), "control/distribution.py",
         "--tests", "tests/test_distribution.py", "--max-children", "1", "--work", str(work),
         "--only", "acroboter.control.distribution.xǁBoundedInputsǁwithin_limits*"],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (row,) = mutation_report.collect(work)
    assert row["module"] == "control/distribution.py"
    judged = {k: v for k, v in row["counts"].items() if k != "not checked"}
    assert judged.get("killed", 0) >= 5, row["counts"]
    assert judged == {"killed": judged["killed"]}, row["survivors"]  # nothing survived, timed out or went untested


def test_a_sample_is_drawn_uniformly_from_the_mutants_mutmut_wrote_and_is_reproducible(tmp_path):
    """--sample N: N distinct names of the selection's mutants (those --only matches), the same for the same seed."""
    meta = tmp_path / "mutants" / "acroboter" / "sim" / "plant.py.meta"
    meta.parent.mkdir(parents=True)
    names = [f"acroboter.sim.plant.x_step__mutmut_{i}" for i in range(1, 41)]
    names += [f"acroboter.sim.plant.x_energy__mutmut_{i}" for i in range(1, 11)]
    meta.write_text(json.dumps({"exit_code_by_key": dict.fromkeys(names)}))
    drawn = mutation.draw(tmp_path, [], 12, seed=7)
    assert len(set(drawn)) == 12 and set(drawn) <= set(names)
    assert mutation.draw(tmp_path, [], 12, seed=7) == drawn and mutation.draw(tmp_path, [], 12, seed=8) != drawn
    only = mutation.draw(tmp_path, ["*x_energy*"], 20, seed=7)  # more asked than there are: all of them
    assert sorted(only) == sorted(n for n in names if "x_energy" in n)
    # uniform: over many seeds every mutant is drawn about 12/50 of the time
    counts = {n: 0 for n in names}
    for seed in range(2000):
        for n in mutation.draw(tmp_path, [], 12, seed):
            counts[n] += 1
    assert max(abs(c / 2000 - 12 / 50) for c in counts.values()) < 0.04


def test_the_sampled_kill_rates_interval_is_wilsons():
    """The 95 % Wilson score interval (Wilson 1927): 95 of 100 gives 0.8882–0.9785 (its textbook value),
    0 of 10 gives 0–0.2775, and it narrows as the sample grows."""
    low, high = mutation_report.wilson_interval(95, 100)
    assert (low, high) == (pytest.approx(0.88825, abs=1e-4), pytest.approx(0.97846, abs=1e-4))
    assert mutation_report.wilson_interval(0, 10) == (pytest.approx(0.0, abs=1e-12), pytest.approx(0.27753, abs=1e-4))
    wide, narrow = mutation_report.wilson_interval(90, 100), mutation_report.wilson_interval(900, 1000)
    assert narrow[1] - narrow[0] < 0.4 * (wide[1] - wide[0])
