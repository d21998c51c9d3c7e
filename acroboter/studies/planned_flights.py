"""How fast can the paper's path be flown? (docs/planning.md): for a crane and a set of winch limits, the
retiming's fastest timing of the spec's path (acroboter.planning) and each method's closed loop on it.

A case is a shipped spec with every winch's limits set to [lower, upper] (its TOML text, as in
acroboter.studies.saturation); the other inputs keep the spec's limits (the shipped cranes' fans and yaw torque
have none). The plan is computed here, never read from a file; each method then flies the written trajectory
from the static start with the spec's limits applied (the bounded distribution, QP saturation), and is measured
by acroboter.studies.saturation.measure from its records alone. The peak fan thrust and yaw torque of the MLM
run are reported too: with unbounded fans they are what the winch limits leave to them.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..model.spec_edits import with_winch_limits
from .saturation import measure

METHODS = ("mlm", "penalty", "iterative-3")


@dataclass(frozen=True)
class Case:
    spec: str  # a shipped spec's name (acroboter.example_spec)
    lower: float  # N, every winch's lower limit
    upper: float  # N, every winch's upper limit

    @property
    def name(self) -> str:
        return f"{self.spec} [{self.lower:g}, {self.upper:g}] N"


# The limit sets on the default and the four-cable crane.
CASES = tuple(Case(spec, 5.0, upper) for spec in ("acroboter", "acroboter_4cable") for upper in (30.0, 60.0, 120.0))


@dataclass
class CaseResult:
    case: str
    spec: str
    winch_limits: list[float]
    margin: float
    planned_s: float
    path_own_s: float
    uniform_s: float  # the best uniform slowdown of the path's own timing (an upper bound the plan must meet)
    edge_wise_s: float | None  # each edge's own timing slowed on its own from rest (the solves' warm start)
    edges_solved: int
    edges_kept_quintic: int  # edges IPOPT did not solve: their own timing slowed from rest is kept (feasible)
    margin_planned: float
    plan_solve_s: float
    certificate_error_mm: float | None
    certificate_margin: float | None
    runs: list[dict] = field(default_factory=list)

    def row(self) -> dict:
        return asdict(self)


def run_case(case: Case, folder: Path, margin: float = 0.05, intervals: int = 120,
             methods=METHODS) -> tuple[CaseResult, object, dict]:
    """Plan `case` and fly it with every method: (the figures, the Plan, {method: Result})."""
    from ..api.crane import Crane
    from ..process.locations import example_spec

    folder.mkdir(parents=True, exist_ok=True)
    spec_path = folder / f"{case.spec}_{case.lower:g}_{case.upper:g}.toml"
    spec_path.write_text(with_winch_limits(example_spec(case.spec).read_text(), case.upper, case.lower))
    crane = Crane.from_toml(spec_path)
    started = time.perf_counter()
    plan = crane.plan(margin=margin, intervals=intervals)  # every edge rest to rest (acroboter.planning.edges)
    solve_s = time.perf_counter() - started
    cert = plan.certificate
    result = CaseResult(
        case=case.name, spec=case.spec, winch_limits=[case.lower, case.upper], margin=margin,
        planned_s=float(plan.duration), path_own_s=float(plan.path_duration), uniform_s=float(plan.uniform_duration),
        edge_wise_s=None if plan.phase_duration is None else float(plan.phase_duration),
        edges_solved=sum(1 for w in plan.solves if w.get("status") == "Solve_Succeeded"),
        edges_kept_quintic=sum(1 for w in plan.solves if w.get("status") == "quintic_slowdown_kept"),
        margin_planned=float(plan.margin_achieved),
        plan_solve_s=solve_s, certificate_error_mm=None if cert is None else float(cert.max_position_error_mm),
        certificate_margin=None if cert is None else float(cert.margin_achieved))
    lower, upper, _ = crane.spec.input_limits()
    names = list(crane.layout.inputs)
    runs = {}
    for method in methods:
        start = time.perf_counter()
        flown = crane.simulate(method, trajectory=plan.trajectory, warm_up=0)
        runs[method] = flown
        row = measure(flown, lower, upper, case.name, "qp", time.perf_counter() - start).row()
        for label, kinds in (("peak_thrust_N", "thrust"), ("peak_yaw_torque_Nm", "torque")):
            cols = [i for i, n in enumerate(names) if kinds in n]
            row[label] = float(np.abs(flown.u[:, cols]).max()) if cols else None
        result.runs.append(row)
    return result, plan, runs
