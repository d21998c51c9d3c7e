"""Generated code is written atomically and verified before use (bad-input safety, issue 10 items 1-2).

A failed or interrupted generation leaves the previous files byte-identical; a spec from elsewhere
cannot overwrite a checked-in crane's generated code; a hand-edited or extra C file and a manifest
whose shapes disagree with the compiled library are refused with a message that names the file.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO, SPEC_DIR

from acroboter.codegen import emit_c as generation
from acroboter.codegen.emit_c import GenerationContext, generate
from acroboter.model.spec import load_spec
from acroboter.runtime.cache import load_model
from acroboter.runtime.compiled import StaleModelError

TOY = Path(__file__).resolve().parent / "specs" / "collocated_toy.toml"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture()
def toy_tree(tmp_path):
    """The toy spec generated once into a temporary generated/ folder."""
    spec = load_spec(TOY)
    root = tmp_path / "generated"
    generate(spec, root)
    return spec, root, snapshot(root / spec.name)


def test_failed_generation_leaves_the_previous_files(toy_tree, monkeypatch):
    spec, root, before = toy_tree
    real_write = GenerationContext.write

    def write_then_fail(self, out_dir):
        real_write(self, out_dir)
        (out_dir / "half_written.c").write_text("/* ... */")
        raise RuntimeError("disk full")

    monkeypatch.setattr(GenerationContext, "write", write_then_fail)
    with pytest.raises(RuntimeError, match="disk full"):
        generate(spec, root)
    assert snapshot(root / spec.name) == before
    assert sorted(p.name for p in root.iterdir()) == [spec.name]  # no temporary folder left


@pytest.mark.parametrize("error", [RuntimeError("does not compile"), KeyboardInterrupt()])
def test_failed_verification_or_interrupt_leaves_the_previous_files(toy_tree, error):
    spec, root, before = toy_tree

    def verify(folder):
        assert (folder / "manifest.json").is_file()  # everything was written before the check
        raise error

    with pytest.raises(type(error)):
        generate(spec, root, verify=verify)
    assert snapshot(root / spec.name) == before
    assert sorted(p.name for p in root.iterdir()) == [spec.name]


def test_swap_failure_puts_the_previous_folder_back(toy_tree, monkeypatch):
    spec, root, before = toy_tree
    real_rename = Path.rename

    def rename(self, target):
        if self.name.startswith(f".{spec.name}.new-"):
            raise OSError("rename refused")
        return real_rename(self, target)

    monkeypatch.setattr(Path, "rename", rename)
    with pytest.raises(OSError):
        generate(spec, root)
    assert snapshot(root / spec.name) == before


def test_interrupted_cli_generation_leaves_the_previous_files(tmp_path):
    """Ctrl-C (SIGINT) while `python -m acroboter.codegen generate` works: exit 130, one line, files unchanged."""
    root = tmp_path / "generated"
    shutil.copytree(REPO / "generated" / "acroboter", root / "acroboter")
    before = snapshot(root / "acroboter")
    proc = subprocess.Popen([sys.executable, "-m", "acroboter", "generate", str(SPEC_DIR / "acroboter.toml"),
                             "--out", str(root)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.0)  # inside the symbolic derivation or the compile check (about 10 s in all)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert snapshot(root / "acroboter") == before
    assert sorted(p.name for p in root.iterdir()) == ["acroboter"]


def test_a_spec_from_elsewhere_cannot_overwrite_a_checked_in_crane(tmp_path):
    stranger = tmp_path / "my_copy.toml"
    stranger.write_text((SPEC_DIR / "acroboter.toml").read_text().replace("mass = 8.0", "mass = 9.0"))
    before = snapshot(REPO / "generated" / "acroboter")
    proc = subprocess.run([sys.executable, "-m", "acroboter", "generate", str(stranger)], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "model_spec/acroboter.toml" in proc.stderr and "would overwrite generated/acroboter/" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert snapshot(REPO / "generated" / "acroboter") == before


def test_generation_checks_that_the_code_compiles(tmp_path, monkeypatch):
    """The CLI's verification compiles the staged C: broken C never replaces working C."""
    from acroboter.cli import generate as cli

    spec = load_spec(TOY)
    root = tmp_path / "generated"
    generate(spec, root)
    before = snapshot(root / spec.name)
    real_write = GenerationContext.write

    def write_broken(self, out_dir):  # a generator bug: broken C, its manifest and metadata consistent with it
        from acroboter.model.fingerprint import meta_source

        written = real_write(self, out_dir)
        (out_dir / f"{spec.name}_phi.c").write_text("this is not C;\n")
        doc = json.loads((out_dir / "manifest.json").read_text())
        doc["files"][f"{spec.name}_phi.c"] = generation.file_digest(out_dir / f"{spec.name}_phi.c")
        (out_dir / f"{spec.name}_meta.c").write_text(meta_source(doc))
        doc["files"][f"{spec.name}_meta.c"] = generation.file_digest(out_dir / f"{spec.name}_meta.c")
        (out_dir / "manifest.json").write_text(json.dumps(doc))
        return written

    monkeypatch.setattr(GenerationContext, "write", write_broken)
    with pytest.raises(cli.GenerationError, match="does not compile"):
        generate(spec, root, verify=cli.compile_check)
    assert snapshot(root / spec.name) == before


def test_generation_checks_the_integrity_of_what_it_wrote(tmp_path, monkeypatch):
    """A staged file whose hash is not the manifest's is refused before compiling: nothing replaces the C."""
    from acroboter.cli import generate as cli

    spec = load_spec(TOY)
    root = tmp_path / "generated"
    generate(spec, root)
    before = snapshot(root / spec.name)
    real_write = GenerationContext.write

    def write_then_edit(self, out_dir):
        written = real_write(self, out_dir)
        (out_dir / f"{spec.name}_phi.c").write_text("/* edited */\n")
        return written

    monkeypatch.setattr(GenerationContext, "write", write_then_edit)
    monkeypatch.setattr("acroboter.runtime.compile_library.build", lambda *a, **k: pytest.fail("compiled"))
    with pytest.raises(cli.GenerationError, match="fails its own integrity check.*phi.c is not what"):
        generate(spec, root, verify=cli.compile_check)
    assert snapshot(root / spec.name) == before


# --- verified, not trusted --------------------------------------------------------------------------


def copy_tree(toy_tree, tmp_path) -> tuple:
    spec, root, _ = toy_tree
    return spec, root, tmp_path / "build"


def test_a_hand_edited_c_file_is_refused(toy_tree, tmp_path):
    spec, root, build = copy_tree(toy_tree, tmp_path)
    edited = root / spec.name / f"{spec.name}_mass_matrix.c"
    text = edited.read_text()
    assert "return 0;" in text
    edited.write_text(text.replace("return 0;", "w[0] = 2.0; return 0;", 1))  # a plausible hand edit
    with pytest.raises(StaleModelError) as info:
        load_model(spec, generated_dir=root, cache_dir=build)
    message = str(info.value)
    assert edited.name in message and "content hash" in message and "acroboter generate" in message
    assert not build.exists()  # refused before anything was compiled


def test_an_extra_c_file_is_refused(toy_tree, tmp_path):
    spec, root, build = copy_tree(toy_tree, tmp_path)
    (root / spec.name / "extra.c").write_text("int x;\n")
    with pytest.raises(StaleModelError, match="extra.c"):
        load_model(spec, generated_dir=root, cache_dir=build)


def test_an_edited_manifest_shape_is_refused_before_compiling(toy_tree, tmp_path):
    """An edited output shape would size a buffer wrong: the manifest's digest (in the generated metadata file)
    refuses it before anything is compiled; the library's own sparsity check stands behind it."""
    spec, root, build = copy_tree(toy_tree, tmp_path)
    manifest_path = root / spec.name / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    outputs = manifest["functions"]["phi_q"]["outputs"]
    rows, cols = outputs[0][1]
    outputs[0][1] = [rows - 1, cols]  # one row short: the call would write past the buffer
    manifest_path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    with pytest.raises(StaleModelError) as info:
        load_model(spec, generated_dir=root, cache_dir=build)
    assert "manifest.json does not describe the generated files" in str(info.value) and "shapes" in str(info.value)
    assert not build.exists()  # refused before anything was compiled


def test_the_manifest_lists_every_generated_file():
    for folder in sorted((REPO / "generated").iterdir()):
        manifest = json.loads((folder / "manifest.json").read_text())
        on_disk = {p.name for p in folder.iterdir()} - {"manifest.json"}
        assert set(manifest["files"]) == on_disk, folder.name
        for name, digest in manifest["files"].items():
            assert generation.file_digest(folder / name) == digest, f"{folder.name}/{name}"


def _git_status(path: Path) -> str:
    return subprocess.run(["git", "status", "--porcelain", "--", str(path)], cwd=REPO, capture_output=True,
                          text=True, check=True).stdout


def test_git_status_stays_clean_after_a_failed_generation_of_a_checked_in_spec(monkeypatch):
    status, before = _git_status(REPO / "generated"), snapshot(REPO / "generated" / "acroboter")

    def fail(self, out_dir):
        (out_dir / "partial.c").write_text("/* half */")
        raise RuntimeError("injected failure")

    monkeypatch.setattr(GenerationContext, "write", fail)
    with pytest.raises(RuntimeError, match="injected failure"):
        generate(load_spec(SPEC_DIR / "acroboter.toml"), REPO / "generated")
    assert _git_status(REPO / "generated") == status  # clean on a fresh clone
    assert snapshot(REPO / "generated" / "acroboter") == before


def test_git_status_stays_clean_after_an_interrupted_generation_of_a_checked_in_spec():
    status, before = _git_status(REPO / "generated"), snapshot(REPO / "generated" / "acroboter")
    proc = subprocess.Popen([sys.executable, "-m", "acroboter", "generate", str(SPEC_DIR / "acroboter.toml")],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode in (0, 130), err  # interrupted, or (on a very fast machine) already done
    assert _git_status(REPO / "generated") == status  # clean on a fresh clone
    assert snapshot(REPO / "generated" / "acroboter") == before


def test_two_checked_in_specs_with_one_name_are_refused(tmp_path, monkeypatch):
    """A copy in model_spec/ that kept the original's name (step 1 of "Model a new crane", forgotten)."""
    from acroboter.cli import generate as cli
    from acroboter.model.spec import SpecError

    specs = tmp_path / "model_spec"
    specs.mkdir()
    original = specs / "acroboter.toml"
    original.write_text((SPEC_DIR / "acroboter.toml").read_text())
    copy = specs / "mycrane.toml"  # sorts after the original
    copy.write_text(original.read_text().replace("mass = 8.0", "mass = 9.0"))
    monkeypatch.setattr(cli, "SPEC_DIR", specs)
    for path in (copy, original):
        with pytest.raises(SpecError, match="in 2 specs of model_spec/"):
            cli.refuse_collisions([(path, load_spec(path))], cli.GENERATED_DIR)


def test_a_truncated_library_is_rebuilt_not_loaded(toy_tree, tmp_path):
    from acroboter.runtime.compile_library import build as build_library

    spec, root, build = copy_tree(toy_tree, tmp_path)
    lib = build_library(spec.name, root / spec.name, build)  # built, not loaded: this process never maps it
    lib.write_bytes(lib.read_bytes()[:1000])  # loading this would crash the process (SIGBUS)
    model = load_model(spec, generated_dir=root, cache_dir=build)
    assert lib.stat().st_size > 1000 and model.term("mass_matrix").shape[0] == model.layout.n


@pytest.mark.parametrize("edit", ["swap two symbols", "drop the functions", "a list"])
def test_an_edited_manifest_is_refused_with_a_message(toy_tree, tmp_path, edit):
    spec, root, build = copy_tree(toy_tree, tmp_path)
    path = root / spec.name / "manifest.json"
    manifest = json.loads(path.read_text())
    if edit == "swap two symbols":  # the same shapes: only the manifest's digest tells
        f = manifest["functions"]
        f["phi_dot"]["symbol"], f["gamma"]["symbol"] = f["gamma"]["symbol"], f["phi_dot"]["symbol"]
        words = "does not describe the generated files"
    elif edit == "drop the functions":
        del manifest["functions"]
        words = "'functions' missing"
    else:
        manifest = [manifest]
        words = "not a JSON object"
    path.write_text(json.dumps(manifest))
    with pytest.raises(StaleModelError, match=words):
        load_model(spec, generated_dir=root, cache_dir=build)
