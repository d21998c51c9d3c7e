"""The stateful controller from the library: the exported C controller's step in Python (`Crane.stateful_controller`)
and the export itself with the constants only the library can compute (`Crane.export_controller`: the static
start q0 and the path's numbers for the C's <name>_path), docs/controller.md."""

from __future__ import annotations

from pathlib import Path

from ..control.controllers import make_controller
from ..control.fast_path import path_table
from ..sim.fast_estimator import make_estimator
from ..sim.stateful_controller import StatefulController

__all__ = ["export_controller", "stateful_controller"]


def stateful_controller(crane, method: str, sensing, iterations, fast: bool, overrides: dict) -> StatefulController:
    """See Crane.stateful_controller."""
    name = crane.method_name(method, iterations)
    chosen = crane.sensing(sensing)
    path, data = crane.path, crane.model.data()  # its own working copy of the model
    controller = make_controller(name, data, path, crane.gains(**overrides), fast=fast)
    return StatefulController(data, path, controller, make_estimator(data, path, chosen, fast=fast))


def controller_constants(crane) -> dict:
    """The keyword arguments codegen.controller_c.build_controller needs from the library: start_q, path_numbers."""
    return {"start_q": crane.equilibrium().q.copy(), "path_numbers": path_table(crane.path)}


def export_controller(crane, method: str, out: str | Path, sensing, mlm_system: str, penalty_system: str,
                      overrides: dict) -> list[Path]:
    """See Crane.export_controller."""
    from ..codegen.controller_c import build_controller, write_controller

    name = crane.method_name(method)
    export = build_controller(crane.spec, name, crane.gains(**overrides), crane.sensing(sensing),
                              spec_path=crane.source, mlm_system=mlm_system, penalty_system=penalty_system,
                              **controller_constants(crane))
    return write_controller(export, Path(out))
