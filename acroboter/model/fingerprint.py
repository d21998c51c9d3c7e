"""What identifies generated code: the code generator's hash and the manifest's hash.

Both the code generator (which writes them into the manifest and the library) and the bindings
(which check them before loading) need these; they live here, below both, so that neither imports
the other.
"""

from __future__ import annotations

import hashlib
import json
from importlib import metadata
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # acroboter/ (this file is acroboter/model/fingerprint.py)
# Sources whose content decides the generated code (besides the spec and CasADi's version), relative
# to the package: the same bytes in a checkout and in an installed wheel give the same hash.
CODEGEN_SOURCES = (
    "codegen/symbolic.py", "codegen/structured.py", "codegen/plant.py", "codegen/generate.py", "model/spec.py",
    "model/schema.py", "model/spec_checks.py", "model/spec_errors.py",
    "model/layout.py", "model/fingerprint.py", "model/physical.py", "model/mjcf_model.py",
)


def casadi_version() -> str:
    """CasADi's version without importing it (the bindings never need CasADi itself)."""
    return metadata.version("casadi")


def codegen_hash() -> str:
    """Hash of the code that turns a spec into C, and of the CasADi version doing it."""
    h = hashlib.sha256(f"casadi {casadi_version()}\n".encode())
    for rel in CODEGEN_SOURCES:
        h.update(rel.encode() + b"\n" + (PACKAGE_DIR / rel).read_bytes())
    return h.hexdigest()


def manifest_hash(manifest: dict) -> str:
    """SHA-256 of the manifest's description of the library (its file list aside): embedded in the
    library, so a manifest edited to name other symbols or shapes is found out."""
    described = {k: v for k, v in manifest.items() if k != "files"}
    return hashlib.sha256(json.dumps(described, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()
