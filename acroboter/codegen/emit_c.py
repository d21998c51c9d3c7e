"""Generation context: register the model's functions, then emit all of them in one place.

Every function takes the same five inputs (q, qd, s, sd, sdd) so the numeric side can share one
set of input buffers across all calls. Output files have stable names `<spec>_<function>.c`, and
the same spec and codegen give the same bytes (no dates, no paths, sorted manifest).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import casadi as ca

from ..model.controller_parameters import runtime_names, runtime_size
from ..model.fingerprint import codegen_hash, file_digest, meta_file, meta_source, source_header
from ..model.mjcf_model import mjcf_xml
from ..model.spec import Spec
from ..process.interrupts import deferred_interrupt
from . import plant_step, solver_terms
from .symbolic import SymbolicModel, build_symbolic_model

INPUT_NAMES = ("q", "qd", "s", "sd", "sdd")

# The generated functions: name -> the model terms it returns (in order).
FUNCTIONS: dict[str, tuple[str, ...]] = {
    "mass_matrix": ("mass_matrix",),
    "bias_forces": ("bias_forces",),
    "phi": ("phi",),
    "phi_q": ("phi_q",),
    "phi_dot": ("phi_dot",),
    "gamma": ("gamma",),
    "sigma": ("sigma",),
    "sigma_q": ("sigma_q",),
    "sigma_dot": ("sigma_dot",),
    "gamma_s": ("gamma_s",),
    "input_matrix": ("input_matrix",),
    "energy": ("kinetic", "potential", "dissipated_power"),
    # One call for everything a controller needs at a state: a ctypes call costs ~1 us, so the
    # hot path makes one call, not eleven.
    "model_terms": (
        "mass_matrix", "bias_forces", "phi", "phi_q", "phi_dot", "gamma",
        "sigma", "sigma_q", "sigma_dot", "gamma_s", "input_matrix",
    ),
}

# The plant's own functions: the same terms with the physical parameters as the input `plant_params`
# (acroboter.model.physical), for the plant's events, impacts and energy; its RK4 step is plant_step.
PLANT_FUNCTIONS: dict[str, tuple[str, ...]] = {
    "plant_terms": ("mass_matrix", "bias_forces", "phi", "phi_q", "phi_dot", "gamma", "input_matrix"),
    "plant_energy": ("kinetic", "potential", "dissipated_power"),
}


def _term(model: SymbolicModel, name: str) -> ca.SX:
    if name == "dissipated_power":  # qd . dD/dqd, the power taken out by damping
        qd = model.inputs[1]
        return ca.dot(qd, ca.gradient(model.dissipation, qd))
    if name == "kinetic":
        return model.kinetic
    if name == "potential":
        return model.potential
    return getattr(model, name)


class GenerationContext:
    """Collects casadi.Functions for one spec and writes them, the manifest and the metadata."""

    def __init__(self, spec: Spec, parametric_plant: bool = True):
        """parametric_plant=False folds the spec's physical parameters into the plant's functions too
        (their `plant_params` input is then empty): the plant of one parameter set, as the controllers'."""
        self.spec = spec
        self.model = build_symbolic_model(spec)
        self.plant_model = build_symbolic_model(spec, parametric=True) if parametric_plant else self.model
        self.functions: dict[str, ca.Function] = {}

    def register(self, name: str, terms: tuple[str, ...]) -> None:
        outputs = [ca.densify(ca.SX(_term(self.model, t))) for t in terms]
        self.functions[name] = ca.Function(
            f"{self.spec.name}_{name}", self.model.inputs, outputs, list(INPUT_NAMES), list(terms), {"cse": True}
        )

    def register_plant(self, name: str, terms: tuple[str, ...]) -> None:
        """Model terms of the plant: the five inputs and the physical parameters `plant_params`."""
        model = self.plant_model
        outputs = [ca.densify(ca.SX(_term(model, t))) for t in terms]
        self.functions[name] = ca.Function(
            f"{self.spec.name}_{name}", [*model.inputs, model.parameters], outputs,
            [*INPUT_NAMES, "plant_params"], list(terms), {"cse": True}
        )

    def register_solver_terms(self, name: str, build) -> None:
        """Controller-shaped terms with the run-time parameter vector p (acroboter.model.controller_parameters)."""
        p = ca.SX.sym("p", runtime_size(self.model.layout.k))
        terms = build(self.model, p)
        self.functions[name] = ca.Function(
            f"{self.spec.name}_{name}",
            [*self.model.inputs, p],
            [ca.densify(ca.SX(v)) for v in terms.values()],
            [*INPUT_NAMES, "p"],
            list(terms),
            {"cse": True},
        )

    def register_all(self) -> GenerationContext:
        for name, terms in FUNCTIONS.items():
            self.register(name, terms)
        self.register_solver_terms("mlm_terms", solver_terms.mlm_terms)
        self.register_solver_terms("penalty_terms", solver_terms.penalty_terms)
        # Called only where inputs are redundant or a limit is hit: the unbounded hot path stays as it was.
        self.register_solver_terms("mlm_bounded_terms", solver_terms.mlm_bounded_terms)
        self.register_solver_terms("penalty_bounded_terms", solver_terms.penalty_bounded_terms)
        self.functions["penalty_iteration"] = solver_terms.penalty_iteration_function(
            self.model, f"{self.spec.name}_penalty_iteration"
        )
        for name, terms in PLANT_FUNCTIONS.items():
            self.register_plant(name, terms)
        rows = solver_terms.independent_rows(self.model)
        self.functions["plant_step"] = plant_step.plant_step_function(self.plant_model, f"{self.spec.name}_plant_step",
                                                                      rows)
        if self.plant_model is not self.model:
            # The plant of the spec's own numbers, folded as the controllers' (an empty plant_params):
            # the nominal plant, bit for bit what it was before parameters were an input, and cheaper.
            self.functions["plant_step_folded"] = plant_step.plant_step_function(
                self.model, f"{self.spec.name}_plant_step_folded", rows)
        return self

    def header(self) -> str:
        return source_header(self.spec.name, ca.__version__, self.spec.model_hash(), codegen_hash())

    def manifest(self) -> dict:
        lay = self.model.layout
        return {
            "spec": self.spec.name,
            "casadi_version": ca.__version__,
            "spec_model_hash": self.spec.model_hash(),
            "codegen_hash": codegen_hash(),
            "layout": {
                "coordinates": lay.coordinates,
                "constraints": lay.constraints,
                "servo_constraints": lay.servo_constraints,
                "inputs": lay.inputs,
                "input_units": lay.input_units,
                "signals": lay.signals,
                "redundant_constraint_rows": list(lay.redundant_rows),
                "independent_constraint_rows": solver_terms.independent_rows(self.model),
                "plant_parameters": list(self.plant_model.parameter_names),
                "parameters": runtime_names(lay.servo_constraints),
            },
            "functions": {
                name: {
                    "symbol": f.name(),
                    "file": f"{f.name()}.c",
                    "inputs": [[f.name_in(i), f.numel_in(i)] for i in range(f.n_in())],
                    # a list, not a dict: the order is the C function's result order
                    "outputs": [[f.name_out(i), list(f.size_out(i))] for i in range(f.n_out())],
                }
                for name, f in self.functions.items()
            },
        }

    def write(self, out_dir: Path) -> list[Path]:
        """Write one C file per function, the MJCF model, the metadata C file and manifest.json into out_dir.

        The manifest lists every other file with its SHA-256, and the metadata file (which the library
        embeds) carries the digest of the manifest's whole content, that list included
        (acroboter.model.fingerprint.manifest_hash): the numeric side refuses a folder whose files, manifest
        or library do not match (acroboter.runtime.integrity), so a hand edit or a half-written file is never used.
        """
        out_dir.mkdir(parents=True, exist_ok=True)
        written = []
        header = self.header()
        for f in self.functions.values():
            cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False, "casadi_int": "long long int"})
            cg.add(f)
            path = out_dir / f"{f.name()}.c"
            path.write_text(header + cg.dump())
            written.append(path)
        # The same crane for MuJoCo (acroboter.model.mjcf_model): checked in and hashed like the C.
        mjcf = out_dir / f"{self.spec.name}.xml"
        mjcf.write_text(mjcf_xml(self.spec))
        written.append(mjcf)
        doc = self.manifest()
        doc["files"] = {path.name: file_digest(path) for path in written}
        meta = out_dir / meta_file(self.spec.name)
        meta.write_text(meta_source(doc))  # the digest of everything above (its own entry aside)
        written.append(meta)
        doc["files"][meta.name] = file_digest(meta)
        manifest = out_dir / "manifest.json"
        manifest.write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
        written.append(manifest)
        return written


def generate(spec: Spec, out_root: Path, verify: Callable[[Path], None] | None = None,
             parametric_plant: bool = True) -> Path:
    """Generate the C for one spec into out_root/<spec name>/, replacing what was there, atomically.

    Everything is written into a temporary folder beside the target, `verify(folder)` (e.g. a
    compile check) runs on it, and only then does it take the target's place (two renames). A
    failure or an interrupt at any point before leaves the previous folder byte-identical and no
    temporary folder behind.
    """
    out_root.mkdir(parents=True, exist_ok=True)
    out_dir = out_root / spec.name
    staging = Path(tempfile.mkdtemp(prefix=f".{spec.name}.new-", dir=out_root))
    staging.chmod(0o755)  # mkdtemp's 0700 would end up on the checked-in folder
    try:
        GenerationContext(spec, parametric_plant).register_all().write(staging)
        if verify is not None:
            verify(staging)
        _swap_in(staging, out_dir)
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # gone already after a successful swap
    return out_dir


def _swap_in(staging: Path, out_dir: Path) -> None:
    """Put the folder `staging` in the place of `out_dir` (which may not exist yet)."""
    if not out_dir.exists():
        staging.rename(out_dir)
        return
    retired = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
    shutil.rmtree(retired, ignore_errors=True)
    with deferred_interrupt():  # the two renames and the clean-up happen together or not at all
        out_dir.rename(retired)
        try:
            staging.rename(out_dir)
        except BaseException:
            retired.rename(out_dir)  # put the previous files back
            raise
        shutil.rmtree(retired, ignore_errors=True)

