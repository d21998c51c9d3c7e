"""A spec's compiled model, found or made on first use: `load_model(spec)`.

The generated C of a spec comes from, in order:

1. ``generated_dir/<spec>/`` when the caller names a folder (strict: it must match the spec);
2. the shipped examples' checked-in C (``generated/`` in a checkout, packaged in a wheel) when the
   spec is one of them, unchanged;
3. otherwise the cache: ``<cache>/generated/<spec>-<key>/``, generated on first use, keyed by the
   spec's model hash and the code generator's hash (which covers CasADi's version), written into a
   temporary folder and renamed into place under a lock.

The library is then compiled into the cache (acroboter.runtime.compile_library), keyed by the sources and flags;
every link from the spec to the library is checked before use (acroboter.runtime.integrity).
This is the one runtime module that may call the code generator: controllers, plant and
simulation only ever see the CompiledModel it returns.
"""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
import tempfile
from pathlib import Path

from ..model.fingerprint import codegen_hash
from ..model.spec import Spec
from ..process.interrupts import remembered_interrupt
from ..process.locations import cache_dir as resolve_cache_dir
from ..process.locations import shipped_generated_folder
from .compile_library import BuildError, cache_lock, cache_write_error, remove_stale_staging
from .compiled import CompiledModel, DamagedLibraryError, NotBuiltError, StaleModelError
from .integrity import regenerate_hint

log = logging.getLogger(__name__)


def load_model(spec: Spec, generated_dir: Path | None = None, cache_dir: Path | None = None,
               build: bool = True) -> CompiledModel:
    """The compiled, bound model of `spec` (see the module docstring for where its code comes from).

    `cache_dir`: where libraries (and generated C of specs that are not shipped) go; default
    $ACROBOTER_CACHE_DIR, else the per-user cache. build=False: never generate or compile, raise
    NotBuiltError instead (what a sweep worker does)."""
    root = resolve_cache_dir(cache_dir)
    if generated_dir is not None:
        model = CompiledModel(spec, Path(generated_dir) / spec.name, root, build=build)
    else:
        source = model_sources(spec, root, generate=build)
        try:
            model = CompiledModel(spec, source, root, build=build)
        except (NotBuiltError, DamagedLibraryError):
            raise  # the C is fine: regenerating it would build the same library path again
        except StaleModelError as err:
            if not build or not source.is_relative_to(root / "generated"):
                raise  # the shipped C, or a folder the caller named: say so, never touch it
            # The cache's own copy was damaged (a file edited or removed): it is ours to remake.
            log.warning("the cached C of spec '%s' is damaged (%s): generating it again", spec.name, err)
            with cache_lock(root, f"generate-{source.parent.name}"):
                shutil.rmtree(source.parent, ignore_errors=True)
            model = CompiledModel(spec, model_sources(spec, root), root)
    log.debug("model '%s': generated C in %s, library %s", spec.name, model.source_dir, model.library_path)
    return model


def shipped_sources(spec: Spec) -> Path | None:
    """The checked-in C of `spec` if it is a shipped example as it was generated, else None. The shipped example
    itself with a missing or unreadable manifest is damaged shipped code: StaleModelError (exit 2) naming the file
    and what restores it, never a silent regeneration into the cache."""
    folder = shipped_generated_folder() / spec.name
    path = folder / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
        problem = None if isinstance(manifest, dict) else "is not a JSON object"
    except FileNotFoundError:
        manifest, problem = None, "is missing"
    except (OSError, ValueError) as err:
        manifest, problem = None, f"cannot be read as JSON ({getattr(err, 'strerror', None) or err})"
    if problem is None:
        if manifest.get("spec_model_hash") == spec.model_hash() and manifest.get("codegen_hash") == codegen_hash():
            return folder
        return None  # another version of the spec or of the generator: the cache's to generate
    if folder.is_dir() and _is_shipped_example(spec):
        raise StaleModelError(f"spec '{spec.name}': the shipped generated C is damaged: {path} {problem}; "
                              f"{regenerate_hint(folder)}")
    return None


def _is_shipped_example(spec: Spec) -> bool:
    """Whether `spec` is one of the shipped examples as its file in the package says it."""
    from ..model.spec import SpecError, load_spec
    from ..process.locations import spec_folder

    example = spec_folder() / f"{spec.name}.toml"
    try:
        return example.is_file() and load_spec(example).model_hash() == spec.model_hash()
    except SpecError:
        return False


def model_sources(spec: Spec, cache_root: Path, generate: bool = True) -> Path:
    """The folder with the generated C of `spec`: the shipped one, or the cache's (made if missing,
    unless generate=False: NotBuiltError)."""
    shipped = shipped_sources(spec)
    if shipped is not None:
        return shipped
    key = hashlib.sha256(f"{spec.model_hash()}\n{codegen_hash()}".encode()).hexdigest()[:16]
    folder = cache_root / "generated" / f"{spec.name}-{key}"
    source = folder / spec.name
    if (source / "manifest.json").is_file():
        return source
    if not generate:
        raise NotBuiltError(f"no generated C for spec '{spec.name}' in {folder}: load the model once with build "
                            "allowed (it generates and compiles there)")
    try:
        with cache_lock(cache_root, f"generate-{folder.name}"):
            return _generate_into(spec, folder, source)
    except OSError as err:
        raise BuildError(cache_write_error(cache_root, err)) from None


def _generate_into(spec: Spec, folder: Path, source: Path) -> Path:
    """Generate `spec` into `folder` (called under its lock): a staging folder, then one rename."""
    if (source / "manifest.json").is_file():  # another process generated it while we waited
        return source
    from ..codegen.emit_c import generate  # only here: loading a shipped model never imports CasADi

    log.info("generating the C of spec '%s' into %s (once per spec version) ...", spec.name, folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(folder.parent, f".{folder.name}.new-")  # a killed process's (we hold the lock)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.new-", dir=folder.parent))
    try:
        with remembered_interrupt() as interrupt:  # CasADi swallows Ctrl-C: honour it before the rename
            generate(spec, staging, verify=lambda _: interrupt.check())
        staging.chmod(0o755)
        if folder.exists():  # an earlier attempt that was damaged or cut short
            shutil.rmtree(folder)
        staging.rename(folder)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return source
