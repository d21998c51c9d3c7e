"""Compile a spec's generated C into a shared library in the cache: `acroboter build [SPEC_NAME ...]`.

A library lands in <cache>/lib/<spec>-<sources hash>/lib<spec>.so, beside the SHA-256 of the file
the build wrote. The hash (of every generated file, the compiler flags and the compiler's name) in
the folder name means a library older than its sources is never picked up, and a rebuilt library
gets a new path, so a process that already loaded the old one can still load the new one (dlopen
returns the library already loaded from a path). The library embeds the same hash in full, its build
key (`<spec>_build_key()`, compiled from a file the build writes): a library is current only when its
checksum matches and it carries its key, and the bindings compare the key after loading it
(acroboter.runtime.integrity). The compiler's version is not part of the key: a worker machine without a
compiler must still find the library. `acroboter build` checks the sources (integrity links 1-3) before
it compiles anything. A build writes into a temporary folder and
renames it into place, under a file lock: two processes building the same library at once end with
one library, and neither ever loads a half-written one.
"""

from __future__ import annotations

import argparse
import fcntl
import hashlib
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager, suppress
from pathlib import Path

from ..model.spec import load_spec
from ..process.cores import usable_cores
from ..process.locations import cache_dir, shipped_generated_folder, spec_folder
from .integrity import verify_sources
from .progress import announce, progress_disabled

log = logging.getLogger(__name__)
# -O2 and IEEE semantics: never -ffast-math, the dynamics must be reproducible to the last bit.
CFLAGS = ("-O2", "-fPIC", "-fno-fast-math")


class BuildError(RuntimeError):
    pass


def _compiler() -> str:
    return os.environ.get("CC", "cc")


def sources_hash(source_dir: Path) -> str:
    h = hashlib.sha256(f"{_compiler()} {' '.join(CFLAGS)}".encode())
    for path in sorted(source_dir.iterdir()):
        if path.is_file():
            h.update(path.name.encode() + b"\n" + path.read_bytes())
    return h.hexdigest()


def library_path(spec_name: str, source_dir: Path, cache_root: Path, key: str | None = None) -> Path:
    """Where the library built from `source_dir` (a generated/<spec_name>/ folder) lives (`key`: its
    sources_hash, when the caller has it already)."""
    key = sources_hash(source_dir) if key is None else key
    return cache_root / "lib" / f"{spec_name}-{key[:16]}" / f"lib{spec_name}.so"


def is_current(lib: Path, key: str) -> bool:
    """The library exists, is the file the build wrote (its SHA-256 sidecar) and carries its build key
    `key` (the sources' hash): a truncated or replaced library, also garbage beside a forged checksum, is
    rebuilt instead of loaded (loading one can crash the process)."""
    digest = lib.with_name(lib.name + ".sha256")
    if not (lib.is_file() and digest.is_file()):
        return False
    data = lib.read_bytes()
    recorded = digest.read_bytes().decode("ascii", errors="replace").strip()
    return hashlib.sha256(data).hexdigest() == recorded and key.encode() + b"\0" in data


def key_source(spec_name: str, key: str) -> str:
    """The C file a build adds to the generated ones: `<spec>_build_key()` returns the sources' hash."""
    return ("/* Written by acroboter's build: the SHA-256 of the compiler's name, its flags and every file of the\n"
            " * generated folder, which the bindings compare before trusting this library. */\n"
            f'const char* {spec_name}_build_key(void) {{ return "{key}"; }}\n')


def compile_jobs() -> int:
    """Translation units compiled at once: the cores this process may use (gcc is single-threaded)."""
    return usable_cores()


class _Compilers:
    """The compiler processes of one build. Each runs in a process group of its own, so that the build, not the
    terminal, decides its end: a Ctrl-C (to the process group, as a terminal sends it, or to this process alone)
    or a failed file stops every one at once (`stop`), instead of waiting for the largest file to compile."""

    def __init__(self):
        self._lock = threading.Lock()
        self._running: set[subprocess.Popen] = set()
        self.stopped = False

    def run(self, command: list[str]) -> tuple[int, str]:
        """The compiler's exit status and its messages (stderr); -SIGTERM once the build was stopped."""
        with self._lock:
            if self.stopped:
                return -signal.SIGTERM, ""
            proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                    process_group=0)
            self._running.add(proc)
        try:
            _, err = proc.communicate()
        except BaseException:  # Ctrl-C while this thread waited (the link step runs in the main thread)
            self.stop()
            raise
        finally:
            with self._lock:
                self._running.discard(proc)
        return proc.returncode, err

    def stop(self) -> None:
        with self._lock:
            self.stopped = True
            running = list(self._running)
        for proc in running:  # the whole group: the driver and its cc1/as (the driver removes its temporary files)
            with suppress(ProcessLookupError, PermissionError):
                os.killpg(proc.pid, signal.SIGTERM)


def _failed(what: str, code: int, err: str, compilers: _Compilers) -> BaseException:
    """The error of a compiler that exited with `code`: a Ctrl-C that reached it is an interrupt, not a failure."""
    if compilers.stopped or code in (-signal.SIGINT, 128 + signal.SIGINT):
        return KeyboardInterrupt()
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else str(-code)
        return BuildError(f"{what} failed: the compiler was killed by {name} (out of memory?)")
    return BuildError(f"{what} failed:\n{err}" if err.strip() else f"{what} failed: the compiler exited with "
                      f"status {code} and printed nothing")


def build(spec_name: str, source_dir: Path, cache_root: Path) -> Path:
    """Compile source_dir/*.c into library_path(...), replacing what is there (atomically): one gcc per
    translation unit, compile_jobs() at once, a progress bar per file on a terminal (tqdm, stderr). Ctrl-C or a
    failed file stops the other compilers at once; the staging folder goes."""
    from tqdm import tqdm

    sources = sorted(source_dir.glob("*.c"))
    if not sources:
        raise BuildError(f"no generated C for spec '{spec_name}' in {source_dir}: run `make generate` first")
    compiler = _compiler()
    if shutil.which(compiler) is None:
        raise BuildError(f"no C compiler '{compiler}' found: install gcc (or set CC) and run `make build`")
    key = sources_hash(source_dir)
    lib = library_path(spec_name, source_dir, cache_root, key)
    lib.parent.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{lib.parent.name}.new-", dir=lib.parent.parent))
    compilers = _Compilers()
    try:
        embedded = staging / f"{spec_name}_build_key.c"  # in the staging folder: the sources stay as generated
        embedded.write_text(key_source(spec_name, key))
        sources = [*sources, embedded]
        def compile_one(src: Path) -> Path:
            obj = staging / (src.stem + ".o")
            code, err = compilers.run([compiler, *CFLAGS, "-c", str(src), "-o", str(obj)])
            if code != 0:
                raise _failed(f"compiling {src.name}", code, err, compilers)
            return obj

        # largest first: the big translation units (the penalty terms) bound the wall time
        ordered = sorted(sources, key=lambda src: src.stat().st_size, reverse=True)
        announce(f"compiling {spec_name} ({len(sources)} files, once: cached in {lib.parent.parent})")
        with ThreadPoolExecutor(max_workers=compile_jobs()) as pool, \
                tqdm(total=len(sources), unit="file", desc=f"compiling {spec_name}", file=sys.stderr,
                     disable=progress_disabled(), leave=False) as bar:
            futures = {pool.submit(compile_one, src): src for src in ordered}
            try:
                for future in as_completed(futures):
                    future.result()  # a failed file raises here (BuildError with gcc's message)
                    bar.set_postfix_str(futures[future].name, refresh=False)
                    bar.update()
            except BaseException:  # Ctrl-C or a failed file: the others stop now, none starts
                compilers.stop()
                pool.shutdown(wait=False, cancel_futures=True)
                raise
        objects = [staging / (src.stem + ".o") for src in sources]  # link order: sorted, deterministic
        built = staging / lib.name
        code, err = compilers.run([compiler, "-shared", *CFLAGS, *map(str, objects), "-lm", "-o", str(built)])
        if code != 0:
            raise _failed(f"linking {lib.name}", code, err, compilers)
        for obj in [*objects, embedded]:
            obj.unlink()
        (staging / (lib.name + ".sha256")).write_text(hashlib.sha256(built.read_bytes()).hexdigest() + "\n")
        staging.chmod(0o755)
        if lib.parent.exists():  # a damaged earlier build: make way (renaming over a folder needs it gone)
            shutil.rmtree(lib.parent)
        staging.rename(lib.parent)  # atomic: the library and its checksum appear together
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # gone already after the rename
    return lib


def remove_stale_staging(folder: Path, prefix: str) -> None:
    """Remove the staging folders `prefix`* in `folder` that a killed process left (call it under the lock of
    what they stage: no live process is writing one then)."""
    with suppress(OSError):
        for entry in folder.iterdir():
            if entry.name.startswith(prefix) and entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)


@contextmanager
def cache_lock(cache_root: Path, name: str):
    """An exclusive lock (flock) on <cache>/locks/<name>.lock, released when the block ends or the
    process dies: concurrent first runs wait for one build instead of doing it twice."""
    folder = cache_root / "locks"
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / f"{name}.lock", "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def cache_write_error(cache_root: Path, err: OSError) -> str:
    return (f"cannot write the model cache {cache_root} ({err.strerror or err}): point ACROBOTER_CACHE_DIR "
            "(or --cache-dir) at a folder you can write")


def ensure_built(spec_name: str, source_dir: Path, cache_root: Path, key: str | None = None) -> Path:
    """The current library of `source_dir`, compiled first if it is missing or damaged (`key`: its
    sources_hash, when the caller has it already)."""
    key = sources_hash(source_dir) if key is None else key
    lib = library_path(spec_name, source_dir, cache_root, key)
    if is_current(lib, key):
        return lib
    try:
        with cache_lock(cache_root, lib.parent.name):
            if not is_current(lib, key):  # another process may have built it while we waited
                remove_stale_staging(lib.parent.parent, f".{lib.parent.name}.new-")
                if lib.exists():
                    log.warning("the library %s is not the file its build wrote (damaged or replaced): compiling it "
                                "again", lib)
                else:
                    log.info("compiling the model library of '%s' into %s (once per version) ...", spec_name,
                             lib.parent)
                build(spec_name, source_dir, cache_root)
    except OSError as err:
        raise BuildError(cache_write_error(cache_root, err)) from None
    return lib


def main(argv: list[str] | None = None) -> int:
    """The command line (`acroboter build` runs it inside the error boundary, codegen_cli.build_main)."""
    parser = argparse.ArgumentParser(prog="acroboter build", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("specs", nargs="*", help="example spec names (default: every shipped example)")
    parser.add_argument("--force", action="store_true",
                        help="recompile even the libraries that are current (same sources, flags, checksum and build "
                             "key): what rebuilds a library that does not load or embeds other hashes")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="where the libraries go (default: $ACROBOTER_CACHE_DIR, else the per-user cache)")
    args = parser.parse_args(argv)
    root, generated = cache_dir(args.cache_dir), shipped_generated_folder()
    # dot-folders are the code generator's staging and retired folders, never a spec's
    names = args.specs or sorted(p.name for p in generated.iterdir() if p.is_dir() and not p.name.startswith("."))
    try:
        for name in names:
            source = generated / name
            if not source.is_dir():
                known = ", ".join(sorted(p.name for p in generated.iterdir() if p.is_dir() and p.name[0] != "."))
                print(f"error: no example '{name}' (the examples are {known}); a spec file of your own is built "
                      "by its first run (`acroboter run --spec FILE`)", file=sys.stderr)
                return 2
            spec_file = spec_folder() / f"{name}.toml"  # its spec, if it is an example: the C must be its
            model_hash = load_spec(spec_file).model_hash() if spec_file.is_file() else None
            verify_sources(source, name, model_hash)  # stale or tampered: StaleModelError (exit 2), nothing compiled
            key = sources_hash(source)
            lib = library_path(name, source, root, key)
            if not args.force and is_current(lib, key):  # incremental: the name carries sources and flags
                print(f"up to date {lib}")
                continue
            with cache_lock(root, lib.parent.name):
                remove_stale_staging(lib.parent.parent, f".{lib.parent.name}.new-")
                print(f"built {build(name, source, root)}")
    except OSError as err:
        raise BuildError(cache_write_error(root, err)) from None
    return 0


if __name__ == "__main__":
    sys.exit(main())
