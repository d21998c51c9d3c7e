"""What the penalty formulation buys you (`acroboter study`): the cases of the redundancy study (the default crane,
with redundant geometric constraints, with a redundant task, under MLM, Penalty and Iterative Penalty) and of the
non-collocation study (the four-input crane under MLM and the penalty methods with every input recovery), each
run through the library (`Crane.simulate`), its outcome whatever it is: figures, a divergence, the method's refusal.
"""

from __future__ import annotations

import functools

import numpy as np

from ..process.locations import spec_folder
from .grid import crane_for, run_cases

SPECS = spec_folder()
REDUNDANT_SPECS = ("acroboter", "acroboter_redundant", "acroboter_redundant_task")
REDUNDANT_METHODS = ("mlm", "penalty", "iterative-3", "iterative-5")
RECOVERY_CASES = (("projected", None), ("kinetic", None), ("eq12", None), ("eq13", None), ("eq15", None),
                  ("kappa", 0.0), ("kappa", 0.5), ("kappa", 1.0))


def run_case(spec_name: str, method: str, duration: float | None, **overrides) -> dict:
    """One closed-loop run; the outcome whatever it is: figures, a divergence, or the method's refusal."""
    from ..control.controllers import SingularSystemError
    from ..control.recovery import RecoveryError
    from ..model.spec import load_spec

    crane = crane_for(load_spec(SPECS / f"{spec_name}.toml"))  # loaded (built if needed) once per spec
    case = {"spec": spec_name, "method": method, **{k: v for k, v in overrides.items() if v is not None}}
    try:
        result = crane.simulate(method, duration=duration, warm_up=0, **overrides)
    except (SingularSystemError, RecoveryError) as err:
        return {**case, "outcome": "refused", "message": str(err)}
    run, winches = result.run, crane.scenario.winch_inputs
    outcome = "diverged" if result.diverged_at is not None else "ran to the end"
    return {**case, "outcome": outcome, "diverged_at_s": result.diverged_at, "divergence": run.divergence,
            "summary": result.summary(), "t": run.t.tolist(),
            "position_error_mm": np.asarray(result.position_error_mm).tolist(),
            "winch_min_N": run.u[:, winches].min(axis=1).tolist() if winches else []}


def redundant_cases() -> list[tuple[str, str, dict]]:
    """(spec, method, gain overrides) of the redundancy study: every spec under every method."""
    return [(name, method, {}) for name in REDUNDANT_SPECS for method in REDUNDANT_METHODS]


def noncollocated_cases() -> list[tuple[str, str, dict]]:
    """The four-input crane: MLM, then both penalty methods under every input recovery."""
    return [("acroboter_4input", "mlm", {})] + [
        ("acroboter_4input", method, {"recovery": recovery, "kappa": kappa})
        for recovery, kappa in RECOVERY_CASES for method in ("penalty", "iterative-3")]


def _run(case: tuple[str, str, dict], duration: float | None) -> dict:
    spec_name, method, overrides = case
    return run_case(spec_name, method, duration, **overrides)


def _run_all(cases: list, duration: float | None, progress) -> list[dict]:
    # In this process, in order: the study is small, and a failure to set up a spec stops it at once.
    return run_cases(functools.partial(_run, duration=duration), cases, on_done=lambda case, result: progress(1))


def study_redundant(duration: float | None, progress) -> list[dict]:
    return _run_all(redundant_cases(), duration, progress)


def study_noncollocated(duration: float | None, progress) -> list[dict]:
    return _run_all(noncollocated_cases(), duration, progress)
