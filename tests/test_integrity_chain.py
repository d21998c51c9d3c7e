"""Integrity end to end (issue 24, item 3): spec -> manifest (file list + hashes) -> sources -> library, each link
checked before use (acroboter.runtime.integrity).

A tamper of the generated folder (a C file edited together with its hash in the manifest, a file list or a hash
edited, the metadata file edited) is refused before anything is compiled: the compile function is replaced by
one that fails the test, and no cache folder appears. A garbage library beside a forged checksum is rebuilt;
one that also carries its build key is refused with a remedy that works, and following it fixes it. Every
case is exit 2 with a message naming the cause and the fix, never a traceback or a library's raw message.
The toy spec (one body, 0.3 s to generate, about 7 s to compile) keeps the compiles few.
"""

from __future__ import annotations

import hashlib
import json
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from acroboter.cli import generate as generate_cli
from acroboter.cli.entry import guarded
from acroboter.codegen.emit_c import generate
from acroboter.model import fingerprint
from acroboter.model.spec import load_spec
from acroboter.runtime import cache as cache_module
from acroboter.runtime import compile_library as build_module
from acroboter.runtime import integrity
from acroboter.runtime.cache import load_model
from acroboter.runtime.compile_library import build, is_current, library_path, sources_hash
from acroboter.runtime.compiled import DamagedLibraryError, StaleModelError

SPECS = Path(__file__).resolve().parent / "specs"
TOY = SPECS / "collocated_toy.toml"
NAME = "collocated_toy"


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    root = tmp_path_factory.mktemp("pristine") / "generated"
    generate(load_spec(TOY), root)
    return root


@pytest.fixture()
def tree(pristine, tmp_path):
    """A fresh copy of the toy's generated folder: (spec, generated root, its folder, a cache that does not exist)."""
    root = tmp_path / "generated"
    shutil.copytree(pristine, root)
    return load_spec(TOY), root, root / NAME, tmp_path / "cache"


@pytest.fixture()
def as_example(tree, monkeypatch):
    """The toy's folder as if it were a shipped example (generated/<name>/, its spec in model_spec/), for
    `acroboter build NAME`, which builds only those."""
    _, root, _, _ = tree
    for module in (build_module, integrity, cache_module):
        monkeypatch.setattr(module, "shipped_generated_folder", lambda: root)
    monkeypatch.setattr(build_module, "spec_folder", lambda: SPECS)
    return tree


@pytest.fixture()
def no_compile(monkeypatch):
    """Any compile fails the test: a refusal must come before it."""
    def refuse(*args, **kwargs):
        raise AssertionError("compiled although the sources were tampered with")

    monkeypatch.setattr(build_module, "build", refuse)


def _rewrite(manifest_path: Path, edit) -> None:
    manifest = json.loads(manifest_path.read_text())
    edit(manifest)
    manifest_path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tamper(folder: Path, how: str) -> str:
    """Tamper with a generated folder; returns words the refusal must contain."""
    manifest = folder / "manifest.json"
    if how == "a C file and its hash":
        edited = folder / f"{NAME}_mass_matrix.c"
        edited.write_text(edited.read_text().replace("return 0;", "w[0] = 2.0; return 0;", 1))
        _rewrite(manifest, lambda m: m["files"].__setitem__(edited.name, _sha(edited)))
        return "manifest.json does not describe the generated files"
    if how == "a file dropped from the list":
        _rewrite(manifest, lambda m: m["files"].pop(f"{NAME}.xml"))
        return "manifest.json does not describe the generated files"
    if how == "a file added with its hash":
        (folder / "notes.txt").write_text("not generated\n")
        _rewrite(manifest, lambda m: m["files"].__setitem__("notes.txt", _sha(folder / "notes.txt")))
        return "manifest.json does not describe the generated files"
    if how == "a hash":
        _rewrite(manifest, lambda m: m["files"].__setitem__(f"{NAME}_phi.c", "0" * 64))
        return f"{NAME}_phi.c is not what the code generator wrote"
    if how == "an output shape":
        def shorter(m):
            rows, cols = m["functions"]["phi_q"]["outputs"][0][1]
            m["functions"]["phi_q"]["outputs"][0][1] = [rows - 1, cols]  # a call would write past the buffer
        _rewrite(manifest, shorter)
        return "manifest.json does not describe the generated files"
    if how == "the metadata file and its hash":
        meta = folder / f"{NAME}_meta.c"
        meta.write_text(meta.read_text() + 'const char* extra(void) { return "x"; }\n')
        _rewrite(manifest, lambda m: m["files"].__setitem__(meta.name, _sha(meta)))
        return "manifest.json does not describe the generated files"
    if how == "the metadata file's entry dropped":
        _rewrite(manifest, lambda m: m["files"].pop(f"{NAME}_meta.c"))
        return f"lists no {NAME}_meta.c"
    raise ValueError(how)


TAMPERS = ["a C file and its hash", "a file dropped from the list", "a file added with its hash", "a hash",
           "an output shape", "the metadata file and its hash", "the metadata file's entry dropped"]


def _clean(err: str) -> None:
    """No traceback, no "internal error", no library's raw message (dlopen's)."""
    for raw in ("Traceback", "internal error", "ELF", "file too short", "cannot open shared object"):
        assert raw not in err, err


@pytest.mark.parametrize("how", TAMPERS)
def test_a_tampered_folder_is_refused_before_any_compile(tree, no_compile, how, capsys):
    spec, root, folder, cache = tree
    words = tamper(folder, how)
    with pytest.raises(StaleModelError) as info:
        load_model(spec, generated_dir=root, cache_dir=cache)
    assert words in str(info.value), str(info.value)
    assert f"acroboter generate SPEC_FILE --out {root}" in str(info.value)  # the fix, for a folder of one's own
    assert not cache.exists()  # nothing compiled, no orphan cache folder
    # on the command line: exit 2, one line
    assert guarded(lambda: load_model(spec, generated_dir=root, cache_dir=cache) and 0)() == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and words in err and err.count("\n") == 1, err
    _clean(err)


@pytest.mark.parametrize("how", ["a C file and its hash", "a file dropped from the list", "an output shape"])
def test_acroboter_build_refuses_a_tampered_example_before_compiling(as_example, no_compile, how, capsys):
    _, root, folder, cache = as_example
    words = tamper(folder, how)
    assert generate_cli.build_main([NAME, "--cache-dir", str(cache)]) == 2
    err = capsys.readouterr().err
    assert words in err and "make generate" in err, err
    _clean(err)
    assert not cache.exists()


def test_following_the_regenerate_advice_fixes_a_tampered_folder(tree, capsys):
    spec, root, folder, cache = tree
    tamper(folder, "a C file and its hash")
    with pytest.raises(StaleModelError) as info:
        load_model(spec, generated_dir=root, cache_dir=cache)
    command = re.search(r"`(acroboter generate [^`]+)`", str(info.value)).group(1)
    argv = shlex.split(command.replace("SPEC_FILE", str(TOY)))[1:]
    assert generate_cli.main([*argv, "--no-compile-check"]) == 0
    model = load_model(spec, generated_dir=root, cache_dir=cache)
    assert model.term("mass_matrix")[0, 0] == spec.bodies[0].mass  # the generator's code, not the edit (w[0] = 2)


def _garbage(lib: Path, payload: bytes) -> None:
    lib.write_bytes(payload)
    lib.with_name(lib.name + ".sha256").write_text(hashlib.sha256(payload).hexdigest() + "\n")  # forged


def test_garbage_beside_a_forged_checksum_is_rebuilt_not_reported_current(as_example, capsys):
    """Its build key is missing: `acroboter build NAME` (no --force) rebuilds it, and so would a run."""
    spec, root, folder, cache = as_example
    lib = build(NAME, folder, cache)
    _garbage(lib, b"\x7fELF garbage" * 100)
    assert not is_current(lib, sources_hash(folder))
    assert generate_cli.build_main([NAME, "--cache-dir", str(cache)]) == 0
    out = capsys.readouterr().out
    assert "up to date" not in out and f"built {lib}" in out
    assert load_model(spec, cache_dir=cache).term("mass_matrix")[0, 0] == spec.bodies[0].mass


def test_garbage_with_its_build_key_and_a_forged_checksum_gets_advice_that_works(as_example, capsys):
    spec, root, folder, cache = as_example
    key = sources_hash(folder)
    lib = build(NAME, folder, cache)
    good = lib.read_bytes()
    _garbage(lib, b"not a library " + key.encode() + b"\0")
    assert generate_cli.build_main([NAME, "--cache-dir", str(cache)]) == 0  # name, checksum, key: "current"
    assert "up to date" in capsys.readouterr().out
    assert guarded(lambda: load_model(spec, cache_dir=cache) and 0)() == 2
    err = capsys.readouterr().err
    assert f"library {lib} cannot be loaded" in err and f"`acroboter build --force {NAME} --cache-dir {cache}`" in err
    _clean(err)
    command = re.search(r"`(acroboter build --force [^`]+)`", err).group(1)
    assert generate_cli.build_main(shlex.split(command)[2:]) == 0  # the advice, as printed
    assert lib.read_bytes() == good  # the same build again (the same process never loaded the garbage)
    assert load_model(spec, cache_dir=cache).term("mass_matrix")[0, 0] == spec.bodies[0].mass


def test_a_library_of_other_sources_under_this_name_gets_advice_that_works(tree, capsys):
    """A loadable library whose embedded hashes are another folder's (name, checksum and key forged)."""
    spec, root, folder, cache = tree
    other = root.parent / "other"
    shutil.copytree(root, other)
    tamper(other / NAME, "a C file and its hash")  # another library: other sources, another manifest digest
    meta = other / NAME / f"{NAME}_meta.c"
    manifest = json.loads((other / NAME / "manifest.json").read_text())
    meta.write_text(fingerprint.meta_source(manifest))
    key = sources_hash(folder)
    foreign = build(NAME, other / NAME, root.parent / "other-cache").read_bytes()
    lib = library_path(NAME, folder, cache, key)
    lib.parent.mkdir(parents=True)
    _garbage(lib, foreign + key.encode() + b"\0")  # its key appended: it passes as current
    assert guarded(lambda: load_model(spec, generated_dir=root, cache_dir=cache) and 0)() == 2
    err = capsys.readouterr().err
    assert "does not hold the code of" in err and "embedded manifest_hash differs" in err, err
    assert f"delete the folder {lib.parent}: the next run compiles it again" in err
    _clean(err)
    shutil.rmtree(lib.parent)  # the advice; "the next run": this process has the foreign library mapped at that path
    check = (f"from pathlib import Path; from acroboter.model.spec import load_spec; "
             f"from acroboter.runtime.cache import load_model; spec = load_spec({str(TOY)!r}); "
             f"print(load_model(spec, generated_dir=Path({str(root)!r}), cache_dir=Path({str(cache)!r}))"
             ".term('mass_matrix')[0, 0])")
    proc = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and float(proc.stdout) == spec.bodies[0].mass, proc.stderr


def test_a_damaged_library_of_ones_own_crane_does_not_regenerate_its_c(tmp_path, monkeypatch):
    """The cache's C is fine: a damaged library is reported (what rebuilds it), not answered by generating the
    C again, which would build the same library path and find the same library."""
    spec = load_spec(TOY)
    cache = tmp_path / "cache"
    sources = cache_module.model_sources(spec, cache)  # the cache's C, generated; compiled, never loaded here
    key = sources_hash(sources)
    lib = build(NAME, sources, cache)
    _garbage(lib, b"not a library " + key.encode() + b"\0")

    def regenerate(*args, **kwargs):
        raise AssertionError("the C was generated again")

    monkeypatch.setattr("acroboter.codegen.emit_c.generate", regenerate)
    with pytest.raises(DamagedLibraryError, match=f"delete the folder {re.escape(str(lib.parent))}"):
        load_model(spec, cache_dir=cache)
    assert sources.is_dir()


# --- what the library embeds covers everything that defines it ---------------------------------------------


def test_the_manifest_digest_covers_the_file_list_and_hashes(pristine):
    manifest = json.loads((pristine / NAME / "manifest.json").read_text())
    digest = fingerprint.manifest_hash(manifest)
    changed = json.loads(json.dumps(manifest))
    changed["files"][f"{NAME}_phi.c"] = "0" * 64
    assert fingerprint.manifest_hash(changed) != digest
    fewer = json.loads(json.dumps(manifest))
    del fewer["files"][f"{NAME}.xml"]
    assert fingerprint.manifest_hash(fewer) != digest
    own = json.loads(json.dumps(manifest))  # the metadata file's own entry is the one left out (it holds the digest)
    own["files"][f"{NAME}_meta.c"] = "0" * 64
    assert fingerprint.manifest_hash(own) == digest
    assert (pristine / NAME / f"{NAME}_meta.c").read_text() == fingerprint.meta_source(manifest)


def test_the_build_key_covers_the_compiler_its_flags_and_every_file(pristine, tmp_path, monkeypatch):
    folder = tmp_path / NAME
    shutil.copytree(pristine / NAME, folder)
    key = sources_hash(folder)
    monkeypatch.setattr(build_module, "CFLAGS", (*build_module.CFLAGS, "-g"))
    assert sources_hash(folder) != key
    monkeypatch.undo()
    monkeypatch.setenv("CC", "another-cc")
    assert sources_hash(folder) != key
    monkeypatch.delenv("CC")
    (folder / "manifest.json").write_text((folder / "manifest.json").read_text() + " ")
    assert sources_hash(folder) != key


def test_the_library_embeds_what_defines_it(tree):
    import ctypes

    spec, root, folder, cache = tree
    model = load_model(spec, generated_dir=root, cache_dir=cache)
    manifest = json.loads((folder / "manifest.json").read_text())
    for what, value in integrity.expected_embedded(manifest, sources_hash(folder)).items():
        fn = getattr(model.lib, f"{NAME}_{what}")
        fn.restype = ctypes.c_char_p
        assert fn().decode() == value, what
    assert fingerprint.casadi_version() in manifest["casadi_version"]  # CasADi: in the codegen hash it embeds
