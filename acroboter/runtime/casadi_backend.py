"""The same model functions evaluated by CasADi's virtual machine (casadi.Function calls).

A drop-in for CompiledModel (same buffers, same `functions[name].call()/.outputs`), so the very
same controllers and plant run on it. It is what a user without code generation would write, and
the reference that `python -m acroboter.bench` compares the compiled path with. Not for hot loops:
each casadi.Function call from Python costs tens of microseconds.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ..model.layout import build_layout
from ..model.spec import Spec
from .compiled import SharedInputs


class CasadiFunction:
    def __init__(self, function, inputs: list[np.ndarray]):
        self.function = function
        self.name = function.name()
        self.inputs = [self._shaped(i, a) for i, a in enumerate(inputs)]
        self.outputs = {}
        for i in range(function.n_out()):
            rows, cols = function.size_out(i)
            self.outputs[function.name_out(i)] = np.zeros(rows if cols == 1 else (rows, cols), order="F")

    def call(self) -> None:
        results = self.function(*self.inputs)
        if not isinstance(results, (list, tuple)):
            results = [results]
        for out, value in zip(self.outputs.values(), results, strict=True):
            out[...] = value.full().reshape(out.shape, order="F")

    def _shaped(self, index: int, flat: np.ndarray) -> np.ndarray:
        """A view of a flat (column-major) buffer in the input's own shape, as casadi wants it."""
        rows, cols = self.function.size_in(index)
        return flat if cols == 1 else flat.reshape((rows, cols), order="F")

    def point_input(self, index: int, address: int) -> None:
        size = self.function.numel_in(index)
        flat = np.ctypeslib.as_array((ctypes.c_double * size).from_address(address))
        self.inputs[index] = self._shaped(index, flat)


class CasadiModel(SharedInputs):
    """The spec's functions as casadi.Function objects behind CompiledModel's interface: built from the
    generator in this process (no C, no compiler), so a change to the generator acts at once."""

    def __init__(self, spec: Spec):
        from acroboter.codegen.emit_c import GenerationContext  # CasADi symbolics: only this backend needs them

        self.spec = spec
        self.layout = build_layout(spec)
        context = GenerationContext(spec).register_all()
        self.manifest = context.manifest()  # the generated folder's manifest.json, as CompiledModel reads it
        self.source_dir = self.library_path = self.cache_root = None  # nothing on disk
        self.functions_source = context.functions  # the casadi.Function objects, shared by every working copy
        self._bind_buffers()

    def _bind_buffers(self) -> None:
        ns = self.layout.n_signals
        self.signals = np.zeros(3 * ns)
        self.buffers: dict[str, np.ndarray] = {
            "s": self.signals[:ns], "sd": self.signals[ns : 2 * ns], "sdd": self.signals[2 * ns :],
        }
        for f in self.functions_source.values():
            for i in range(f.n_in()):
                self.buffers.setdefault(f.name_in(i), np.zeros(f.numel_in(i)))
        self.q, self.qd, self.p = self.buffers["q"], self.buffers["qd"], self.buffers["p"]
        self.parameters_owner = None
        self.s, self.sd, self.sdd = self.buffers["s"], self.buffers["sd"], self.buffers["sdd"]
        self._inputs = (self.q, self.qd, self.s, self.sd, self.sdd)
        self.functions = {
            name: CasadiFunction(f, [self.buffers[f.name_in(i)] for i in range(f.n_in())])
            for name, f in self.functions_source.items()
        }

    def data(self) -> CasadiModel:
        """A working copy with buffers and outputs of its own (as CompiledModel.data)."""
        other = object.__new__(type(self))
        for key in ("spec", "layout", "manifest", "source_dir", "library_path", "cache_root", "functions_source"):
            setattr(other, key, getattr(self, key))
        other._bind_buffers()
        return other

    def bind(self, name: str) -> CasadiFunction:
        f = self.functions[name].function
        return CasadiFunction(f, [self.buffers[f.name_in(i)] for i in range(f.n_in())])
