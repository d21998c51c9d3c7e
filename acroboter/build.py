"""Compile a spec's generated C into a shared library: `python -m acroboter.build [SPEC_NAME ...]`.

The library lands in build/<spec>/lib<spec>-<sources hash>.so. The hash in the name means a
library older than generated/ is never picked up (it is rebuilt), and a rebuilt library gets a new
path, so a process that already loaded the old one can still load the new one (dlopen returns the
library already loaded from a path).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
GENERATED_DIR = REPO / "generated"
BUILD_DIR = REPO / "build"
# -O2 and IEEE semantics: never -ffast-math, the dynamics must be reproducible to the last bit.
CFLAGS = ("-O2", "-fPIC", "-fno-fast-math")


class BuildError(RuntimeError):
    pass


def library_path(spec_name: str, build_dir: Path = BUILD_DIR, generated_dir: Path = GENERATED_DIR) -> Path:
    """Where the library built from the current generated/<spec_name>/ lives."""
    return build_dir / spec_name / f"lib{spec_name}-{sources_hash(generated_dir / spec_name)[:16]}.so"


def sources_hash(source_dir: Path) -> str:
    h = hashlib.sha256(" ".join(CFLAGS).encode())
    for path in sorted(source_dir.iterdir()):
        if path.is_file():
            h.update(path.name.encode() + b"\n" + path.read_bytes())
    return h.hexdigest()


def is_current(spec_name: str, generated_dir: Path = GENERATED_DIR, build_dir: Path = BUILD_DIR) -> bool:
    """The library of the current sources exists and is the file the build wrote (its SHA-256 sidecar):
    a truncated or replaced library is rebuilt instead of loaded (loading one can crash the process)."""
    lib = library_path(spec_name, build_dir, generated_dir)
    digest = lib.with_name(lib.name + ".sha256")
    if not (lib.is_file() and digest.is_file()):
        return False
    return hashlib.sha256(lib.read_bytes()).hexdigest() == digest.read_text().strip()


def build(spec_name: str, generated_dir: Path = GENERATED_DIR, build_dir: Path = BUILD_DIR) -> Path:
    """Compile generated/<spec_name>/*.c into build/<spec_name>/lib<spec_name>-<sources hash>.so."""
    source_dir = generated_dir / spec_name
    sources = sorted(source_dir.glob("*.c"))
    if not sources:
        raise BuildError(
            f"no generated C for spec '{spec_name}' in {source_dir}: run `make generate` first"
        )
    compiler = os.environ.get("CC", "cc")
    if shutil.which(compiler) is None:
        raise BuildError(f"no C compiler '{compiler}' found: install gcc (or set CC) and run `make build`")
    out_dir = build_dir / spec_name
    obj_dir = out_dir / "obj"
    obj_dir.mkdir(parents=True, exist_ok=True)

    def compile_one(src: Path) -> Path:
        obj = obj_dir / (src.stem + ".o")
        result = subprocess.run([compiler, *CFLAGS, "-c", str(src), "-o", str(obj)], capture_output=True, text=True)
        if result.returncode != 0:
            raise BuildError(f"compiling {src.name} failed:\n{result.stderr}")
        return obj

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        objects = list(pool.map(compile_one, sources))
    lib = library_path(spec_name, build_dir, generated_dir)
    tmp = lib.with_suffix(f".{os.getpid()}.tmp")
    result = subprocess.run(
        [compiler, "-shared", *CFLAGS, *map(str, objects), "-lm", "-o", str(tmp)], capture_output=True, text=True
    )
    if result.returncode != 0:
        raise BuildError(f"linking {lib.name} failed:\n{result.stderr}")
    digest, digest_tmp = lib.with_name(lib.name + ".sha256"), lib.with_name(f"{lib.name}.sha256.{os.getpid()}.tmp")
    digest_tmp.write_text(hashlib.sha256(tmp.read_bytes()).hexdigest() + "\n")
    tmp.replace(lib)  # atomic: a concurrent loader never sees a half-written library
    digest_tmp.replace(digest)
    for old in out_dir.glob(f"lib{spec_name}-*.so*"):
        if old not in (lib, digest) and not old.name.endswith(".tmp"):
            old.unlink(missing_ok=True)
    return lib


def ensure_built(spec_name: str, generated_dir: Path = GENERATED_DIR, build_dir: Path = BUILD_DIR) -> Path:
    if not is_current(spec_name, generated_dir, build_dir):
        print(f"building the compiled model for '{spec_name}' (make build) ...", file=sys.stderr)
        build(spec_name, generated_dir, build_dir)
    return library_path(spec_name, build_dir, generated_dir)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m acroboter.build", description=__doc__)
    parser.add_argument("specs", nargs="*", help="spec names (default: every folder in generated/)")
    parser.add_argument("--force", action="store_true",
                        help="recompile even the libraries that are current (same sources, flags and checksum)")
    args = parser.parse_args(argv)
    # dot-folders are the code generator's staging and retired folders, never a spec's
    names = args.specs or sorted(p.name for p in GENERATED_DIR.iterdir() if p.is_dir() and not p.name.startswith("."))
    try:
        for name in names:
            if not args.force and is_current(name):  # incremental: the name carries sources and flags
                print(f"up to date {library_path(name).relative_to(REPO)}")
                continue
            lib = build(name)
            print(f"built {lib.relative_to(REPO)}")
    except BuildError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
