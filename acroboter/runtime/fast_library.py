"""The fast path's compiled step (acroboter.codegen.fast_step), found or made on first use: `load_fast_step`.

Its C is generated into ``<cache>/generated/fast-<name>/<name>/`` (a staging folder renamed into place under a
lock, as acroboter.runtime.cache does for a spec's model) and compiled by acroboter.runtime.compile_library into
``<cache>/lib/<name>-<sources hash>/lib<name>.so`` (-O2 -fPIC, never fast-math; the library carries its build key
and checksum like the model's). The name carries the key of everything the C depends on (fast_step.fast_key):
the gains, z and the limits are run-time inputs, so one library serves every gain set of a method.

The function is bound once with ctypes (acroboter.runtime.compiled.BoundFunction): its inputs are the model's own
q, qd, s, sd, sdd and p buffers plus the caller's limits buffer, its outputs preallocated: one foreign call a step,
no allocation. This is, with acroboter.runtime.cache and acroboter.runtime.casadi_backend, a runtime module that may
call the code generator.
"""

from __future__ import annotations

import ctypes
import logging
import shutil
import tempfile
from pathlib import Path

import numpy as np

from ..model.settings import Gains
from ..process.interrupts import remembered_interrupt
from .compile_library import BuildError, cache_lock, cache_write_error, ensure_built, remove_stale_staging
from .compiled import BoundFunction, CompiledModel, DamagedLibraryError

log = logging.getLogger(__name__)

__all__ = ["FastEstimatorBinding", "FastPathUnavailable", "FastStepBinding", "load_fast_estimator", "load_fast_step"]


class FastPathUnavailable(RuntimeError):
    """This controller cannot have the fast path (the reason says why); the reference path is used."""


class FastStepBinding:
    """The bound fast step: `call()` evaluates at the model's buffers and `limits`; outputs in `u`, `qdd`, ...

    `path_call(table, signals)` -> call(t): the path's signals at t (codegen.fast_step.path_source, from the path's
    numbers in `table`) into `signals` and the step, one foreign call; `path_flat(table, signals)` -> flat(t): the
    signals alone (for integral action, whose σ needs them before the step)."""

    def __init__(self, function: BoundFunction, limits: np.ndarray, has_qdd: bool, name: str, library: Path,
                 lib: ctypes.CDLL):
        self.function, self.limits, self.has_qdd, self.name, self.library = function, limits, has_qdd, name, library
        out = function.outputs
        self.u, self.qdd, self.within, self.rcond = out["u"], out["qdd"], out["within"], out["rcond"]
        self.call = function.call
        self._run, self._flat = getattr(lib, f"{name}_run"), getattr(lib, f"{name}_flat")
        self._run.restype = ctypes.c_int
        self._run.argtypes = [ctypes.c_void_p, ctypes.c_double, *[ctypes.c_void_p] * 5]
        self._flat.restype = None
        self._flat.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]

    def path_call(self, table: np.ndarray, signals: np.ndarray):
        run, fixed = self._run, self.function._call_args[:4]
        at, into = table.ctypes.data, signals.ctypes.data

        def call(t: float) -> None:
            if run(at, t, into, *fixed) != 0:
                raise RuntimeError(f"{self.name} failed")

        return call

    def path_flat(self, table: np.ndarray, signals: np.ndarray):
        flat, at, into = self._flat, table.ctypes.data, signals.ctypes.data
        return lambda t: flat(at, t, into)


def load_fast_step(model, method: str, gains: Gains, penalty_system: str = "auto") -> FastStepBinding:
    """The fast step of `method` for `model` (a CompiledModel), generated and compiled on first use.

    FastPathUnavailable where it cannot be built (another backend, a formulation the export refuses: the message
    names the cause); BuildError where the compiler fails (exit 3, as for the model's library)."""
    if not isinstance(model, CompiledModel):
        raise FastPathUnavailable(f"the model backend {type(model).__name__} has no compiled library to extend")
    from ..codegen.fast_step import FAST_OUTPUTS, fast_key, fast_name

    spec, lay = model.spec, model.layout
    key = fast_key(spec, method, gains, penalty_system)
    name = fast_name(spec, method, gains.recovery, key)
    root = model.cache_root
    folder = root / "generated" / f"fast-{name}"
    source = folder / name
    has_qdd = _generate(spec, method, gains, penalty_system, name, root, folder, source)
    lib_path = ensure_built(name, source, root)
    lib = _open(lib_path, "the fast step's library")
    limits = np.zeros(3 * lay.l)
    inputs = [model.q, model.qd, model.s, model.sd, model.sdd, model.p, limits]
    sizes = {"u": [lay.l, 1], "qdd": [lay.n, 1], "within": [1, 1], "rcond": [1, 1]}
    function = BoundFunction(lib, name, inputs, [(o, sizes[o]) for o in FAST_OUTPUTS])
    return FastStepBinding(function, limits, has_qdd, name, lib_path, lib)


def _generate(spec, method: str, gains: Gains, penalty_system: str, name: str, root: Path, folder: Path,
              source: Path) -> bool:
    """<name>.c into `source` unless it is there (under the cache's lock); whether the step reports q̈."""

    def make(target: Path) -> str:
        from ..codegen.fast_step import build_fast_step, write_fast_step
        from ..codegen.step_graph import ExportError

        try:
            fast = build_fast_step(spec, method, gains, name, penalty_system)
        except ExportError as err:
            raise FastPathUnavailable(str(err)) from None
        write_fast_step(fast, target)
        return "1" if fast.has_qdd else "0"

    return _generated(name, root, folder, source, make, "the fast control step") == "1"


def _generated(name: str, root: Path, folder: Path, source: Path, make, what: str) -> str:
    """The folder `source` made by make(target) -> its note (kept in the file `note`) unless it is there, under the
    cache's lock, staged and renamed into place; the note."""
    note = source / "note"
    if note.is_file():
        return note.read_text().strip()
    try:
        with cache_lock(root, f"generate-{folder.name}"):
            if note.is_file():  # another process made it while we waited
                return note.read_text().strip()
            log.info("generating %s %s into %s (once per version) ...", what, name, folder)
            folder.parent.mkdir(parents=True, exist_ok=True)
            remove_stale_staging(folder.parent, f".{folder.name}.new-")
            staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.new-", dir=folder.parent))
            try:
                with remembered_interrupt() as interrupt:
                    text = make(staging / name)
                    (staging / name / "note").write_text(text + "\n")
                    interrupt.check()
                staging.chmod(0o755)
                if folder.exists():
                    shutil.rmtree(folder)
                staging.rename(folder)
            finally:
                shutil.rmtree(staging, ignore_errors=True)
            return text
    except OSError as err:
        raise BuildError(cache_write_error(root, err)) from None


class FastEstimatorBinding:
    """The compiled estimator (acroboter.codegen.estimator_c) with its state struct, bound once: `view(field)` is a
    numpy view of a field (its offset from the library's <name>_offsets), the four entry points take pointers."""

    def __init__(self, lib: ctypes.CDLL, name: str, n: int, delay: int, library: Path):
        from ..codegen.estimator_c import OFFSET_FIELDS

        self.name, self.library = name, library
        offsets = (ctypes.c_longlong * (len(OFFSET_FIELDS) + 1))()
        getattr(lib, f"{name}_offsets")(offsets)
        size = int(offsets[0])
        self.state = np.zeros((size + 7) // 8)  # 8-byte aligned, as the struct needs
        raw = self.state.view(np.uint8)
        counts = {"acc": (delay + 1) * n, "violation": 1, "jump": 1}
        self._views: dict[str, np.ndarray] = {}
        for field, offset in zip(OFFSET_FIELDS, offsets[1:], strict=True):
            if field == "k":
                dtype, count = np.int64, 1
            elif field in ("started", "coasted", "prev_valid", "status", "reason", "rejected", "distrust"):
                dtype, count = np.int32, 1
            else:
                dtype, count = np.float64, counts.get(field, n)
            width = np.dtype(dtype).itemsize
            self._views[field] = raw[offset : offset + width * count].view(dtype)
        # the two doubles and the seven ints the records read, adjacent in the struct: one view each
        self._views["scalars"] = raw[offsets[1 + OFFSET_FIELDS.index("violation")] :][:16].view(np.float64)
        self._views["ints"] = raw[offsets[1 + OFFSET_FIELDS.index("started")] :][:28].view(np.int32)
        self.at = self.state.ctypes.data
        pointer = ctypes.c_void_p

        def bind(suffix: str, restype, *argtypes):
            fn = getattr(lib, f"{name}_estimator_{suffix}")
            fn.restype, fn.argtypes = restype, [pointer, *argtypes]
            return fn

        # each takes the state's address first (self.at)
        self.start = bind("start", None, pointer)
        self.reinit = bind("reinit", None)
        self.applied = bind("applied", None, pointer)
        self.update = bind("update", ctypes.c_int, pointer, pointer, pointer)

    def view(self, field: str) -> np.ndarray:
        return self._views[field]


def load_fast_estimator(model, sensing) -> FastEstimatorBinding:
    """The compiled estimator of `sensing` for `model` (a CompiledModel), generated and compiled on first use."""
    if not isinstance(model, CompiledModel):
        raise FastPathUnavailable(f"the model backend {type(model).__name__} has no compiled library to extend")
    from ..codegen.estimator_c import estimator_key

    spec = model.spec
    key = estimator_key(spec, sensing)
    name = f"{spec.name}_estimator_{key[:12]}"
    root = model.cache_root
    folder = root / "generated" / f"fast-{name}"
    source = folder / name

    def make(target: Path) -> str:
        from ..codegen.estimator_c import build_estimator, write_estimator

        write_estimator(build_estimator(spec, sensing, name), target)
        return "estimator"

    _generated(name, root, folder, source, make, "the fast estimator")
    lib_path = ensure_built(name, source, root)
    lib = _open(lib_path, "the fast estimator's library")
    return FastEstimatorBinding(lib, name, model.layout.n, sensing.delay_periods, lib_path)


def _open(lib_path, what: str) -> ctypes.CDLL:
    """A built library, loaded; a damaged one is named with its remedy (remove its folder: rebuilt on next use)."""
    try:
        return ctypes.CDLL(str(lib_path))
    except OSError as err:
        raise DamagedLibraryError(f"{what} {lib_path} cannot be loaded ({err}): remove {lib_path.parent} and run "
                                  "again") from None
