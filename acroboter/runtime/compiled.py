"""Python bindings over a spec's compiled model library.

The library is loaded once with ctypes, each function is bound once, and every argument, result
and work buffer is preallocated. All functions read the same five input buffers (q, qd, s, sd,
sdd): write the state there once, then call as many functions as needed; each call is a single
ctypes call (~1 us) that writes into its own preallocated numpy outputs (column-major, as CasADi
stores them).
"""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

import numpy as np

from ..model.layout import Layout, build_layout
from ..model.spec import Spec
from .compile_library import ensure_built, is_current, library_path, sources_hash
from .integrity import (
    DamagedLibraryError,
    StaleModelError,
    check_library,
    expected_embedded,
    library_remedy,
    verify_sources,
)

__all__ = ["BoundFunction", "CompiledModel", "SharedInputs", "DamagedLibraryError", "NotBuiltError", "StaleModelError"]
log = logging.getLogger(__name__)

_REAL_P = ctypes.POINTER(ctypes.c_double)
_INT = ctypes.c_longlong


class NotBuiltError(StaleModelError):
    """The library is not compiled and compiling was not allowed."""


# Outputs that are matrices whatever their shape (the others with one column are vectors).
MATRIX_OUTPUTS = frozenset({
    "mass_matrix", "phi_q", "sigma_q", "input_matrix", "schur", "minv_w", "penalty_matrix", "recovery_gain",
    "hessian", "servo_map",
})

class BoundFunction:
    """One generated function with preallocated outputs; call() evaluates at the shared inputs."""

    def __init__(self, lib: ctypes.CDLL, symbol: str, inputs: list[np.ndarray], outputs: list[tuple[str, list[int]]]):
        self.name = symbol
        self._fn = getattr(lib, symbol)
        self._fn.restype = ctypes.c_int
        self._fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        work = getattr(lib, f"{symbol}_work")
        work.argtypes = [ctypes.POINTER(_INT)] * 4
        work.restype = ctypes.c_int
        sz = [_INT() for _ in range(4)]
        work(*map(ctypes.byref, sz))
        n_arg, n_res, n_iw, n_w = (int(v.value) for v in sz)
        if n_arg < len(inputs):
            raise StaleModelError(f"{symbol} takes {n_arg} inputs, expected {len(inputs)}: run `make generate`")
        _check_shapes(lib, symbol, [a.size for a in inputs], outputs)
        self.inputs = inputs
        # casadi may need more argument slots than inputs (scratch); keep ours, pad with NULL.
        ptrs_in = [a.ctypes.data for a in inputs]
        self._args = (ctypes.c_void_p * n_arg)(*ptrs_in, *([None] * (n_arg - len(ptrs_in))))
        # Column vectors come back 1-D; matrices column-major (CasADi's dense layout), also when they
        # have one column (one input: H is n x 1).
        self.outputs = {
            name: np.zeros(rows if cols == 1 and name not in MATRIX_OUTPUTS else (rows, cols), order="F")
            for name, (rows, cols) in outputs
        }
        ptrs = [o.ctypes.data for o in self.outputs.values()]
        self._res = (ctypes.c_void_p * n_res)(*ptrs, *([None] * (n_res - len(ptrs))))
        self._iw = np.zeros(max(n_iw, 1), dtype=np.int64)
        self._w = np.zeros(max(n_w, 1))
        # Pre-converted pointers: the per-call cost is then one foreign call.
        self._call_args = (
            ctypes.addressof(self._args),
            ctypes.addressof(self._res),
            self._iw.ctypes.data,
            self._w.ctypes.data,
            0,
        )

    def call(self) -> None:
        if self._fn(*self._call_args) != 0:
            raise RuntimeError(f"{self.name} failed")

    def point_input(self, index: int, address: int) -> None:
        """Read input `index` from another (contiguous, long enough) memory block, e.g. a table row."""
        self._args[index] = address


def _sparsity(lib: ctypes.CDLL, symbol: str, which: str, index: int) -> tuple[int, int, int]:
    """(rows, columns, nonzeros) of input or output `index` from the library's own sparsity pattern."""
    fn = getattr(lib, f"{symbol}_sparsity_{which}")
    fn.argtypes = [_INT]
    fn.restype = ctypes.POINTER(_INT)
    pattern = fn(index)
    rows, cols = int(pattern[0]), int(pattern[1])
    # CasADi's compact form: [rows, cols, 1] is dense (a CCS colind starts at 0); otherwise
    # [rows, cols, colind (cols + 1)..., row...] with colind[cols] = the number of nonzeros.
    return rows, cols, rows * cols if int(pattern[2]) == 1 else int(pattern[2 + cols])


def _check_shapes(lib: ctypes.CDLL, symbol: str, input_sizes: list[int], outputs: list) -> None:
    """Buffers are sized from the manifest: the compiled function must agree, or a call would write
    out of bounds. Inputs: as many numbers as the buffer; outputs: the manifest's dense shape."""
    counts = {}
    for which in ("in", "out"):
        fn = getattr(lib, f"{symbol}_n_{which}")
        fn.restype = _INT
        counts[which] = int(fn())
    if counts["in"] != len(input_sizes) or counts["out"] != len(outputs):
        raise StaleModelError(
            f"{symbol} in the library has {counts['in']} inputs and {counts['out']} outputs, the manifest "
            f"{len(input_sizes)} and {len(outputs)}: the manifest does not describe this library; regenerate"
        )
    for i, size in enumerate(input_sizes):
        rows, cols, _ = _sparsity(lib, symbol, "in", i)
        if rows * cols != size:
            raise StaleModelError(f"{symbol} input {i} is {rows}x{cols} in the library but {size} numbers in the "
                                  "manifest: regenerate")
    for i, (name, (rows, cols)) in enumerate(outputs):
        shape = _sparsity(lib, symbol, "out", i)
        if shape != (rows, cols, rows * cols):
            raise StaleModelError(f"{symbol} output '{name}' is {shape[0]}x{shape[1]} with {shape[2]} nonzeros in "
                                  f"the library but a dense {rows}x{cols} in the manifest: regenerate")


class SharedInputs:
    """What every model backend offers over its five shared input buffers (q, qd, s, sd, sdd) and its
    `functions` (each with `call()` and preallocated `outputs`): CompiledModel and the CasADi VM's CasadiModel."""

    def set_inputs(self, q=None, qd=None, s=None, sd=None, sdd=None) -> None:
        """Copy the given inputs into the shared buffers (others keep their values)."""
        for buf, val in zip(self._inputs, (q, qd, s, sd, sdd), strict=True):
            if val is not None:
                buf[:] = val

    def evaluate(self, name: str, q=None, qd=None, s=None, sd=None, sdd=None) -> dict[str, np.ndarray]:
        """Convenience (not for hot loops): set inputs, call one function, return copies of its outputs."""
        self.set_inputs(q, qd, s, sd, sdd)
        fn = self.functions[name]
        fn.call()
        return {k: v.copy() for k, v in fn.outputs.items()}

    def term(self, name: str, q=None, qd=None, s=None, sd=None, sdd=None) -> np.ndarray:
        """One model term (e.g. 'mass_matrix', 'gamma') as a new array."""
        return self.evaluate(name, q, qd, s, sd, sdd)[name]


class CompiledModel(SharedInputs):
    """All generated functions of one spec, bound to shared input buffers q, qd, s, sd, sdd."""

    def __init__(self, spec: Spec, source_dir: Path, cache_root: Path, build: bool = True):
        """Bind the generated code in `source_dir` (a generated/<spec>/ folder, checked against the
        spec and by content hash) compiled into the cache at `cache_root` (on first use).
        acroboter.runtime.cache.load_model finds both for a spec. build=False: a missing library is a
        NotBuiltError instead of a compilation (e.g. on a worker machine that must not compile)."""
        self.spec = spec
        self.layout: Layout = build_layout(spec)
        self.source_dir = source_dir
        # the chain spec -> manifest -> files, before anything is compiled (acroboter.runtime.integrity)
        self.manifest = verify_sources(source_dir, spec.name, spec.model_hash())
        key = sources_hash(source_dir)
        lib_path = library_path(spec.name, source_dir, cache_root, key)
        if not build and not is_current(lib_path, key):
            raise NotBuiltError(f"no compiled library for spec '{spec.name}' at {lib_path}: build it first "
                                f"(`acroboter build {spec.name}` for an example, or load the model once with "
                                "build allowed)")
        lib_path = ensure_built(spec.name, source_dir, cache_root, key)  # BuildError: cannot run (exit 3)
        self.library_path = lib_path
        self.cache_root = cache_root  # also where acroboter.runtime.fast_library puts the fast steps
        remedy = library_remedy(spec.name, source_dir, cache_root, lib_path)
        try:
            self.lib = ctypes.CDLL(str(lib_path))
        except OSError as err:  # its checksum and key match, yet it does not load: replaced, or another machine's
            log.debug("dlopen(%s): %s", lib_path, err)
            raise DamagedLibraryError(f"library {lib_path} cannot be loaded (it is not a library this machine can "
                                      f"load, although its checksum matches: replaced or damaged): {remedy}"
                                      ) from None
        # the files -> library link: everything that defines the library is what it embeds
        check_library(self.lib, spec.name, expected_embedded(self.manifest, key), lib_path, source_dir, remedy)

        self._bind_buffers()

    # What a working copy (data()) shares with its model: nothing it writes.
    SHARED = ("spec", "layout", "source_dir", "manifest", "library_path", "cache_root", "lib")

    def _bind_buffers(self) -> None:
        # One buffer per input name, shared by every function of this object that reads that input.
        self.buffers: dict[str, np.ndarray] = {}
        # s, ṡ, s̈ are views of one block, so a single assignment sets all three.
        ns = self.layout.n_signals
        self.signals = np.zeros(3 * ns)
        self.buffers.update(s=self.signals[:ns], sd=self.signals[ns : 2 * ns], sdd=self.signals[2 * ns :])
        for info in self.manifest["functions"].values():
            for name, size in info["inputs"]:
                self.buffers.setdefault(name, np.zeros(size))
        self.q, self.qd = self.buffers["q"], self.buffers["qd"]
        self.s, self.sd, self.sdd = self.buffers["s"], self.buffers["sd"], self.buffers["sdd"]
        self.p = self.buffers["p"]  # the controllers' run-time p (model.controller_parameters)
        self.parameters_owner = None  # the controller whose gains are in p
        self._inputs = (self.q, self.qd, self.s, self.sd, self.sdd)
        self.functions: dict[str, BoundFunction] = {
            name: BoundFunction(self.lib, info["symbol"], [self.buffers[i] for i, _ in info["inputs"]],
                                info["outputs"])
            for name, info in self.manifest["functions"].items()
        }

    def data(self) -> CompiledModel:
        """A working copy (MuJoCo's MjModel/MjData split): the same loaded library, spec, layout and manifest, and
        input buffers, outputs and work arrays of its own. Each run, controller and thread works on its own copy,
        so two of them never share a number they write (acroboter.api.crane.Crane gives every run one)."""
        other = object.__new__(type(self))
        other.__dict__.update({key: self.__dict__[key] for key in self.SHARED})
        other._bind_buffers()
        return other

    def bind(self, name: str) -> BoundFunction:
        """A second binding of function `name` with outputs of its own (inputs: the shared buffers,
        re-pointable with point_input), e.g. to chain calls without copying."""
        info = self.manifest["functions"][name]
        return BoundFunction(self.lib, info["symbol"], [self.buffers[i] for i, _ in info["inputs"]], info["outputs"])
