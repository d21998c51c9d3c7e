"""`make mutation`'s small sample (docs/mutation.md): the tool runs from this checkout, mutmut judges every
mutant of one function by the distribution's oracle tests, and the report counts them. The full runs are
`make mutation` (hours on 2 cores); this keeps the pipeline from rotting between them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tools"))

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
