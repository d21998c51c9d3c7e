"""The exported stateful controller (acroboter.codegen.controller_c) compiled and bound in-process with ctypes, for
the bench and the tests that feed it what a Python run recorded: `load_exported_controller(folder, name)`.

`compile_shared` compiles C sources with the project's flags (acroboter.runtime.compile_library.CFLAGS: -O2 -fPIC, never
fast-math) into a shared library and loads it.
"""

from __future__ import annotations

import ctypes
import os
import subprocess
from pathlib import Path

import numpy as np

from ..model.c_templates import render

__all__ = ["ExportedController", "compile_shared", "load_exported_controller"]


def compile_shared(sources: list[Path], lib_path: Path, what: str) -> ctypes.CDLL:
    """`sources` compiled into the shared library `lib_path` (the project's flags: -O2 -fPIC, no fast-math; headers
    from the sources' folder), loaded."""
    from .compile_library import CFLAGS

    include = str(sources[0].parent)
    done = subprocess.run([os.environ.get("CC", "cc"), *CFLAGS, "-shared", "-I", include, *map(str, sources), "-o",
                           str(lib_path), "-lm"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"compiling {what} failed:\n{done.stderr}")
    return ctypes.CDLL(str(lib_path))


class ExportedController:
    """A compiled stateful controller: init(q0, signals), step(y, t, signals) -> code with the command in `u`,
    reset(), reinit(), path(t) -> the C's signals at t; `state_bytes`: sizeof its state struct."""

    def __init__(self, lib: ctypes.CDLL, name: str, n_inputs: int, n_signals: int):
        self.name, self.lib = name, lib
        size = getattr(lib, f"{name}_state_size")
        size.restype = ctypes.c_size_t
        self.state_bytes = int(size())
        self.state = np.zeros(self.state_bytes // 8 + 1)  # 8-byte aligned
        self.u = np.zeros(n_inputs)
        self._signals = np.zeros(3 * n_signals)
        pointer = ctypes.c_void_p
        fns = {}
        for call, args in (("init", [pointer, pointer, pointer]), ("reset", [pointer]), ("reinit", [pointer]),
                           ("step", [pointer, pointer, ctypes.c_double, pointer, pointer])):
            fn = getattr(lib, f"{name}_{call}")
            fn.restype, fn.argtypes = ctypes.c_int, args
            fns[call] = fn
        self._fns = fns
        path = getattr(lib, f"{name}_path")
        path.restype, path.argtypes = None, [ctypes.c_double, pointer]
        self._path = path
        self._at = self.state.ctypes.data

    def init(self, q0: np.ndarray, signals: np.ndarray) -> int:
        q0 = np.ascontiguousarray(q0, dtype=float)  # held here: the C reads them during the call
        signals = np.ascontiguousarray(signals, dtype=float)
        return self._fns["init"](self._at, q0.ctypes.data, signals.ctypes.data)

    def reset(self) -> int:
        return self._fns["reset"](self._at)

    def reinit(self) -> int:
        return self._fns["reinit"](self._at)

    def step(self, y: np.ndarray, t: float, signals: np.ndarray) -> int:
        y = np.ascontiguousarray(y, dtype=float)
        signals = np.ascontiguousarray(signals, dtype=float)
        return self._fns["step"](self._at, y.ctypes.data, t, signals.ctypes.data, self.u.ctypes.data)

    def path(self, t: float) -> np.ndarray:
        """The exported <name>_path at t (a view, overwritten by the next call)."""
        self._path(t, self._signals.ctypes.data)
        return self._signals


def load_exported_controller(folder: Path, name: str, n_inputs: int, n_signals: int) -> ExportedController:
    """<name>.c and <name>_functions.c in `folder` (as write_controller leaves them) compiled and bound."""
    folder = Path(folder)
    (folder / "state_size.c").write_text(render("state_size.c", NAME=name))
    sources = [folder / f for f in (f"{name}.c", f"{name}_functions.c", "state_size.c")]
    lib = compile_shared(sources, folder / f"lib{name}.so", f"the exported controller {name}")
    return ExportedController(lib, name, n_inputs, n_signals)
