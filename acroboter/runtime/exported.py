"""The exported stateful controller (acroboter.codegen.controller_c) compiled and bound in-process with ctypes, for
the bench and the tests that feed it what a Python run recorded: `load_exported_controller(folder, name)`.

`compile_shared` compiles C sources with the project's flags (acroboter.runtime.compile_library.CFLAGS: -O2 -fPIC,
never fast-math) into a shared library and loads it. What it compiled is kept in the cache
(<cache>/exported/<name>-<hash>/: the hash of the compiler and its version, the flags, the sources and the other C files
and headers of their folder; the SHA-256 of the library beside it): the same sources again (a second bench, another
test of the same controller) are copied from there, after their checksum is checked, instead of compiled again. Each
caller still loads its own copy at its own path, so two loads never share the C's static data.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from ..model.c_templates import render

__all__ = ["ExportedController", "compile_shared", "load_exported_controller"]


@functools.cache
def _compiler_identity(compiler: str) -> str:
    """The compiler's name and its own account of its version (`cc --version`): another gcc is another key."""
    try:
        done = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=30)
        return f"{compiler}\n{done.stdout}"
    except (OSError, subprocess.SubprocessError):
        return compiler  # no compiler: nothing compiles, and a kept library is still found


def compiled_key(sources: list[Path]) -> str:
    """What a library compiled from `sources` (one folder's files) depends on, hashed: the compiler and its version,
    the flags, the sources in their order and every other file of their folder (the headers they include)."""
    from .compile_library import CFLAGS

    folder = sources[0].parent
    if any(p.parent != folder for p in sources):
        raise ValueError("compile_shared: the sources must be in one folder (it is their include path)")
    compiler = os.environ.get("CC", "cc")
    h = hashlib.sha256(f"{_compiler_identity(compiler)} {' '.join(CFLAGS)} -shared -lm".encode())
    others = sorted(p for p in folder.iterdir()
                    if p.is_file() and p.suffix in (".h", ".inc", ".c") and p not in sources)
    for path in [*sources, *others]:
        h.update(path.name.encode() + b"\n" + path.read_bytes() + b"\0")
    return h.hexdigest()


def _cached(entry: Path) -> bytes | None:
    """The library kept at `entry`, if its bytes are those its checksum sidecar names (else None: compile again)."""
    digest = entry.with_name(entry.name + ".sha256")
    try:
        data, recorded = entry.read_bytes(), digest.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return data if hashlib.sha256(data).hexdigest() == recorded else None


def _umask() -> int:
    """The process's umask, read without setting it (os.umask would change it for every thread meanwhile)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


def _write_atomically(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.partial.")
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.chmod(tmp, 0o755 & ~_umask())  # as the compiler leaves a library (mkstemp's file is the owner's alone)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def compile_shared(sources: list[Path], lib_path: Path, what: str, cache: Path | None = None) -> ctypes.CDLL:
    """`sources` compiled into the shared library `lib_path` (the project's flags: -O2 -fPIC, no fast-math; headers
    from the sources' folder), loaded; taken from the cache (`cache`: default acroboter.cache_dir()) when the same
    sources were compiled before (see the module)."""
    from ..process.locations import cache_dir
    from .compile_library import CFLAGS

    key = compiled_key(sources)
    entry = (cache_dir() if cache is None else Path(cache)) / "exported" / f"{lib_path.stem}-{key[:16]}" / lib_path.name
    data = _cached(entry)
    if data is not None:
        _write_atomically(lib_path, data)
        return ctypes.CDLL(str(lib_path))
    include = str(sources[0].parent)
    done = subprocess.run([os.environ.get("CC", "cc"), *CFLAGS, "-shared", "-I", include, *map(str, sources), "-o",
                           str(lib_path), "-lm"], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"compiling {what} failed:\n{done.stderr}")
    data = lib_path.read_bytes()
    try:  # the library first, its checksum last: a reader never takes a half-written entry for a whole one
        _write_atomically(entry, data)
        _write_atomically(entry.with_name(entry.name + ".sha256"), hashlib.sha256(data).hexdigest().encode())
    except OSError:  # a cache that cannot be written (read-only, full) only costs the next compile
        pass
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
