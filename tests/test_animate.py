"""`acroboter animate`: the video decodes with the promised frames, what it draws is the crane that q and
the spec describe (checked against independent formulas), slack cables look slack, bad input exits 2."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest

from acroboter.cli import animate
from acroboter.cli.run import main as run_main
from acroboter.model.spec import load_spec
from acroboter.report.animation.matplotlib_frames import MatplotlibFrames
from acroboter.report.animation.mujoco_frames import MujocoFrames, probe_gl
from acroboter.report.animation.scene import SLACK_COLOUR, AnimationInputError, frame_rows, load, spec_of_run

DURATION = 1.0


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert run_main(["--method", "penalty", "--duration", str(DURATION), "--out", str(out), "--no-plots", "-q"]) == 0
    return out


@pytest.fixture(scope="module")
def loaded(results):
    return load(results)


def _columns(path):
    with path.open() as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


@pytest.mark.needs_animation
def test_mp4_decodes_with_one_frame_per_instant(results, tmp_path):
    import imageio.v2 as imageio

    out = tmp_path / "a.mp4"
    assert animate.main([str(results), "--out", str(out), "--fps", "10", "--size", "321x240",
                         "--renderer", "matplotlib", "-q"]) == 0
    reader = imageio.get_reader(out)
    frames = [f for f in reader]
    assert len(frames) == int(DURATION * 10) + 1  # t = 0, 0.1, ..., 1.0
    assert frames[0].shape == (240, 322, 3)  # an odd width grows by one pixel (yuv420p)
    assert frames[-1].std() > 10  # something drawn, not a blank frame
    assert not list(tmp_path.glob(".*partial*"))


@pytest.mark.needs_animation
def test_default_output_and_gif(results):
    assert animate.main([str(results), "--gif", str(results / "a.gif"), "--gif-width", "200", "--fps", "5",
                         "--renderer", "matplotlib", "-q"]) == 0
    assert (results / "animation_penalty.mp4").stat().st_size > 0
    from PIL import Image

    with Image.open(results / "a.gif") as gif:
        assert gif.n_frames == int(DURATION * 8 / 2.5) + 1 and gif.size[0] == 200


def test_frame_rows_follow_the_clock():
    t = np.arange(0, 2751) / 50.0  # the 55 s scenario at 50 Hz
    rows = frame_rows(t, 25.0, 1.0)
    assert len(rows) == 1376 and rows[1] == 2 and rows[-1] == 2750
    fast = frame_rows(t, 8.0, 2.5)
    assert len(fast) == 177 and fast[1] == 16


def test_cable_ends_are_the_body_points_of_q(results, loaded):
    """Independently of build_scene: p = r + ξ1 u + ξ2 v + ξ3 w from the CSV's q columns and the spec file."""
    spec = load_spec(json.loads((results / "summary.json").read_text())["provenance"]["spec_file"])
    header, rows = _columns(results / "penalty.csv")
    row = len(rows) // 2
    value = dict(zip(header, (float(v) for v in rows[row]), strict=True))

    def point(end):
        if "." not in end:
            a = spec.anchor(end)
            return np.array([value.get(f"anchor_{end}_{x}_m", a.position[k]) for k, x in enumerate("xyz")])
        body, name = end.split(".")
        xi = spec.body(body).point(name)
        return np.array([value[f"q_{body}.r_{x}_m"] + sum(xi[k] * value[f"q_{body}.{e}_{x}"]
                                                          for k, e in enumerate("uvw")) for x in "xyz"])

    scene = loaded.scene
    for c, cable in enumerate(spec.cables):
        a, b = point(cable.ends[0]), point(cable.ends[1])
        np.testing.assert_allclose(scene.ends[row, c], [a, b], atol=1e-12)
        if cable.winch is not None:
            assert not value[f"cable_{cable.name}_slack"]
            assert abs(np.linalg.norm(b - a) - value[f"q_{cable.name}.length_m"]) < 1e-6
        else:
            assert abs(np.linalg.norm(b - a) - cable.length) < 1e-6
    # what the artists were given at that row is that geometry
    frames = MatplotlibFrames(scene, "penalty", (320, 240))
    frames.update(row)
    for c, line in enumerate(frames.cable_lines):
        np.testing.assert_allclose(np.array(line.get_data_3d()).T, scene.ends[row, c], atol=1e-12)
    su = frames.axis_lines["SU"]
    r = np.array([value[f"q_SU.r_{x}_m"] for x in "xyz"])
    tip = np.array(su[2].get_data_3d())[:, 1]  # w, drawn from r
    np.testing.assert_allclose(tip - r, scene.axis_length["SU"] * np.array([value[f"q_SU.w_{x}"] for x in "xyz"]),
                               atol=1e-12)
    assert scene.ceiling_z == max(float(np.max(a[:, 2])) for a in scene.anchors.values())


def test_a_slack_cable_is_drawn_dashed_and_grey(results, tmp_path):
    folder = tmp_path / "slack"
    shutil.copytree(results, folder)
    header, rows = _columns(folder / "penalty.csv")
    col = header.index("cable_L2_slack")
    rows[3][col] = "1"
    with (folder / "penalty.csv").open("w", newline="") as f:
        csv.writer(f).writerows([header, *rows])
    scene = load(folder).scene
    frames = MatplotlibFrames(scene, "penalty", (320, 240))
    c = scene.cables.index("L2")
    frames.update(3)
    line = frames.cable_lines[c]
    assert line.get_linestyle() == "--" and line.get_color() == SLACK_COLOUR
    assert frames.cable_lines[c - 1].get_linestyle() == "-"
    frames.update(4)  # taut again: solid and coloured by its tension
    assert line.get_linestyle() == "-" and line.get_color() != SLACK_COLOUR
    before = frames.render(3)
    assert before.shape == (240, 320, 3)


def test_the_spec_is_taken_from_the_provenance_text(results, tmp_path):
    """A folder that carries the spec's TOML needs no path: the recorded one may be gone."""
    folder = tmp_path / "moved"
    shutil.copytree(results, folder)
    summary = json.loads((folder / "summary.json").read_text())
    prov = summary["provenance"]
    text = prov.pop("spec_toml", None) or open(prov["spec_file"], encoding="utf-8").read()
    prov["spec_file"] = str(tmp_path / "gone.toml")
    summary["spec"] = "not-an-example"
    (folder / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(AnimationInputError, match="--spec FILE"):
        load(folder)
    prov["spec_toml"] = text
    (folder / "summary.json").write_text(json.dumps(summary))
    assert load(folder).spec.model_hash() == prov["spec_model_hash"]


def _with_provenance(results, folder, edit) -> None:
    shutil.copytree(results, folder)
    summary = json.loads((folder / "summary.json").read_text())
    edit(summary["provenance"])
    (folder / "summary.json").write_text(json.dumps(summary))


def _heavier(text: str) -> str:
    assert text.count("mass = 8.0") == 1  # the SU's
    return text.replace("mass = 8.0", "mass = 9.0")


def test_spec_text_that_does_not_match_its_recorded_hash_is_refused(results, tmp_path, capsys):
    """summary.json's spec text edited: drawing it could show another crane. Refused (exit 2, before any frame),
    naming the cause and the fixes; the fix --spec FILE works."""
    folder = tmp_path / "edited"
    _with_provenance(results, folder, lambda prov: prov.update(spec_toml=_heavier(prov["spec_toml"])))
    with pytest.raises(AnimationInputError, match="does not match the recorded spec_sha256"):
        load(folder)
    gif = tmp_path / "a.gif"
    err = _fails([str(folder), "--no-mp4", "--gif", str(gif), "--renderer", "matplotlib", "-q"], capsys,
                 "does not match the recorded spec_sha256", "re-run `acroboter run`", "--spec FILE")
    assert "Traceback" not in err and "internal error" not in err and not gif.exists()
    spec_file = json.loads((results / "summary.json").read_text())["provenance"]["spec_file"]
    assert load(folder, spec_file=spec_file).spec.model_hash() == load(results).spec.model_hash()  # the fix


def test_spec_text_is_checked_by_model_hash_without_its_file_hash(results, tmp_path):
    """A folder that records no spec_sha256: the text's model must be the recorded one; with no hash at all the
    text cannot be checked and is refused."""
    intact = tmp_path / "intact"
    _with_provenance(results, intact, lambda prov: prov.pop("spec_sha256"))
    assert load(intact).spec.model_hash() == load(results).spec.model_hash()
    edited = tmp_path / "edited"
    _with_provenance(results, edited, lambda prov: (prov.pop("spec_sha256"),
                                                    prov.update(spec_toml=_heavier(prov["spec_toml"]))))
    with pytest.raises(AnimationInputError, match="not the crane of the recorded spec_model_hash"):
        load(edited)
    bare = tmp_path / "bare"
    _with_provenance(results, bare, lambda prov: (prov.pop("spec_sha256"), prov.pop("spec_model_hash")))
    with pytest.raises(AnimationInputError, match="no recorded hash"):
        load(bare)


def test_the_recorded_spec_text_is_the_files_bytes(results):
    """run records the spec's bytes as text (no newline translation), so their SHA-256 is spec_sha256."""
    import hashlib

    prov = json.loads((results / "summary.json").read_text())["provenance"]
    assert hashlib.sha256(prov["spec_toml"].encode("utf-8")).hexdigest() == prov["spec_sha256"]


def _fails(argv, capsys, *fragments):
    assert animate.main(argv) == 2
    err = capsys.readouterr().err
    for fragment in fragments:
        assert fragment in err, err
    return err


@pytest.mark.needs_animation
def test_bad_input_exits_2(results, tmp_path, capsys):
    _fails([str(tmp_path / "nowhere"), "-q"], capsys, "nothing at", "results folder")
    _fails([str(results), "--method", "mlm", "-q"], capsys, "--method mlm", "penalty")
    folder = tmp_path / "old"
    shutil.copytree(results, folder)
    header, rows = _columns(folder / "penalty.csv")
    keep = [i for i, h in enumerate(header) if not h.startswith("q_")]
    with (folder / "penalty.csv").open("w", newline="") as f:
        csv.writer(f).writerows([[r[i] for i in keep] for r in [header, *rows]])
    _fails([str(folder), "-q"], capsys, "no column q_", "re-run `acroboter run`")
    with pytest.raises(SystemExit) as info:
        animate.main([str(results), "--size", "big"])
    assert info.value.code == 2


# --- the MuJoCo renderer ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gl():
    """The MUJOCO_GL value that gives an OpenGL context here (EGL through Mesa on CI), else skip."""
    backend, why = probe_gl()
    if backend is None:
        pytest.skip(f"MuJoCo's offscreen renderer cannot run here: {why}")
    return backend


@pytest.fixture(scope="module")
def results_2s(tmp_path_factory):
    out = tmp_path_factory.mktemp("run2")
    assert run_main(["--method", "penalty", "--duration", "2", "--out", str(out), "--no-plots", "-q"]) == 0
    return out


@pytest.mark.needs_mujoco
@pytest.mark.needs_animation
def test_mujoco_mp4_decodes_with_one_frame_per_instant(gl, results_2s, tmp_path, monkeypatch):
    import imageio.v2 as imageio

    monkeypatch.setenv("MUJOCO_GL", gl)
    out = tmp_path / "m.mp4"
    assert animate.main([str(results_2s), "--out", str(out), "--fps", "10", "--size", "320x240",
                         "--renderer", "mujoco", "--gif", str(tmp_path / "m.gif"), "--gif-width", "160", "-q"]) == 0
    frames = [f for f in imageio.get_reader(out)]  # not list(): the reader's len() is inf
    assert len(frames) == 21 and frames[0].shape == (240, 320, 3)
    assert frames[-1].std() > 10
    band = round(240 * 0.05)  # below the clock: the crane itself moved between the first and the last frame
    assert np.abs(frames[0][band:].astype(int) - frames[-1][band:].astype(int)).max() > 60
    from PIL import Image

    with Image.open(tmp_path / "m.gif") as gif:
        assert gif.n_frames == int(2 * 8 / 2.5) + 1 and gif.size == (160, 120)


def _project(frames, point):
    """Pixel (column, row) of a world point, from the camera's pose alone (a pinhole with MuJoCo's fovy)."""
    cam = frames.camera
    a, e = np.radians(cam.azimuth), np.radians(cam.elevation)
    forward = np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])
    right = np.cross(forward, [0, 0, 1])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    p = np.asarray(point) - (np.array(cam.lookat) - cam.distance * forward)
    width, height = frames.size
    f = height / 2 / np.tan(np.radians(frames.model.vis.global_.fovy) / 2)
    return np.array([width / 2 + f * (p @ right) / (p @ forward), height / 2 - f * (p @ up) / (p @ forward)])


@pytest.mark.needs_mujoco
def test_mujoco_draws_a_slack_cable_where_the_cable_is(gl, results_2s, monkeypatch):
    """The same instant with cable L2 taut and then slack: the image changes only along L2 as an independent
    pinhole projects its recorded ends, and the taut tendon has the colormap's colour of its tension."""
    from matplotlib import colormaps

    monkeypatch.setenv("MUJOCO_GL", gl)
    scene = load(results_2s).scene
    row, c = len(scene.t) // 2, scene.cables.index("L2")
    assert not scene.slack[row, c]
    frames = MujocoFrames(scene, spec_of_run(json.loads((results_2s / "summary.json").read_text()), results_2s),
                          "penalty", (480, 360))
    try:
        taut = frames.render(row).astype(int)
        lo, hi = scene.tension_range
        expected = colormaps["viridis"]((scene.tension[row, c] - lo) / (hi - lo))
        np.testing.assert_allclose(frames.model.tendon_rgba[frames.tendons[c]], expected, atol=1e-6)
        scene.slack[row, c] = True
        slack = frames.render(row).astype(int)
    finally:
        frames.close()
    changed = np.argwhere(np.abs(taut - slack).max(axis=2) > 20)[:, ::-1]  # (column, row) pixels
    assert len(changed) > 15
    a, b = (_project(frames, p) for p in scene.ends[row, c])
    along = np.clip((changed - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
    distance = np.linalg.norm(changed - (a + along[:, None] * (b - a)), axis=1)
    assert distance.max() < 4, distance.max()


@pytest.mark.needs_mujoco
@pytest.mark.needs_animation
def test_renderer_choice_without_gl(results, tmp_path, monkeypatch, capsys, caplog):
    # patched where choose_renderer looks it up
    monkeypatch.setattr(animate, "probe_gl", lambda: (None, "MUJOCO_GL=egl: no EGL device"))
    assert animate.main([str(results), "--renderer", "mujoco", "--out", str(tmp_path / "x.mp4")]) == 3
    err = capsys.readouterr().err
    assert "MUJOCO_GL=egl" in err and "MUJOCO_GL=osmesa" in err and "--renderer matplotlib" in err
    assert not (tmp_path / "x.mp4").exists()
    with caplog.at_level("INFO", logger="acroboter"):
        assert animate.main([str(results), "--out", str(tmp_path / "y.mp4"), "--fps", "4", "--size", "160x120"]) == 0
    assert any("renderer: matplotlib" in r.getMessage() and "no EGL device" in r.getMessage() for r in caplog.records)


# --- outputs checked before any work; a diverged run says so; the log line; the GIF's colours ----------------


def _refused(argv, capsys, *fragments):
    """Exit 2 from the command line's checks, before load() reads anything."""
    with pytest.raises(SystemExit) as info:
        animate.main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    for fragment in fragments:
        assert fragment in err, err
    assert "internal error" not in err and "partial" not in err and "Traceback" not in err
    return err


def test_outputs_are_checked_before_any_work(results, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(animate, "load", lambda *a: pytest.fail("the outputs were not checked before the work"))
    r = str(results)
    _refused([r, "--out", str(tmp_path / "video"), "-q"], capsys, "--out", "ending in .mp4", "no extension")
    _refused([r, "--out", str(tmp_path / "a.gif"), "-q"], capsys, "'.gif'", "use --gif")
    _refused([r, "--out", str(tmp_path / "a.avi"), "-q"], capsys, "'.avi'")
    _refused([r, "--gif", str(tmp_path / "a.mp4"), "-q"], capsys, "--gif", "ending in .gif", "use --out")
    _refused([r, "--out", "/proc/a.mp4", "-q"], capsys, "/proc is the kernel's file system", "--out /proc/a.mp4")
    _refused([r, "--gif", "/proc/a.gif", "--no-mp4", "-q"], capsys, "--gif /proc/a.gif")
    missing = tmp_path / "nonexist"
    _refused([r, "--out", str(missing / "a.mp4"), "-q"], capsys, f"the folder {missing} does not exist")
    _refused([r, "--gif", str(missing / "a.gif"), "--no-mp4", "-q"], capsys, f"the folder {missing} does not exist")
    assert not missing.exists()  # no parent is created
    _refused([r, "--gif", str(tmp_path / "a.gif"), "--gif-width", "3840", "-q"], capsys,
             "argument --gif-width: expected a whole number 64 <= gif_width <= 1920 (pixels), found 3840")


@pytest.mark.needs_animation
def test_an_existing_folder_as_output_gets_the_default_name(results, tmp_path, caplog):
    with caplog.at_level("INFO", logger="acroboter"):
        assert animate.main([str(results), "--out", str(tmp_path), "--gif", str(tmp_path), "--fps", "0.5",
                             "--gif-fps", "0.5", "--gif-width", "64", "--size", "96x72",
                             "--renderer", "matplotlib"]) == 0
    assert (tmp_path / "animation_penalty.mp4").stat().st_size > 0
    assert (tmp_path / "animation_penalty.gif").stat().st_size > 0
    line = next(r.getMessage() for r in caplog.records if "drawn with" in r.getMessage())
    assert "(1 frame," in line and "frames" not in line and "diverged" not in line  # one frame: singular


def _diverged_copy(results, tmp_path, at=0.9):
    folder = tmp_path / "diverged"
    shutil.copytree(results, folder)
    summary = json.loads((folder / "summary.json").read_text())
    summary["methods"]["penalty"]["diverged_at_s"] = at
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


@pytest.mark.needs_animation
def test_a_diverged_run_says_so(results, tmp_path, caplog):
    from acroboter.report.animation.matplotlib_frames import render_rows

    folder = _diverged_copy(results, tmp_path)
    with caplog.at_level("INFO", logger="acroboter"):
        assert animate.main([str(folder), "--fps", "4", "--size", "160x120", "--renderer", "matplotlib"]) == 0
    assert any("diverged at t = 0.90 s" in r.getMessage() and "stops there" in r.getMessage() for r in caplog.records)
    data = load(folder)
    assert data.scene.diverged_at == 0.9
    assert load(results).scene.diverged_at is None
    rows = frame_rows(data.scene.t, 10.0, 1.0)
    frames = list(render_rows(data.scene, data.spec, rows, (320, 240), "penalty", note_from=len(rows) - 1))
    plain = MatplotlibFrames(data.scene, "penalty", (320, 240)).render(int(rows[-1]))
    assert np.array_equal(frames[0], MatplotlibFrames(data.scene, "penalty", (320, 240)).render(int(rows[0])))
    changed = np.abs(frames[-1].astype(int) - plain.astype(int)).max(axis=2) > 60
    assert changed.sum() > 50  # the note drawn on the last frame, not on the first
    frames_obj = MatplotlibFrames(data.scene, "penalty", (320, 240))
    assert frames_obj.note.get_text() == "diverged at t = 0.90 s"


@pytest.mark.needs_mujoco
def test_mujoco_diverged_note_and_gif_colours(gl, results_2s, tmp_path, monkeypatch):
    """The MuJoCo renderer draws the divergence note, and a tendon's colour in the decoded GIF is its
    colormap's colour (the cables lit flat, a palette that keeps them): the main cable (~177 N) stays yellow."""
    from matplotlib import colormaps
    from PIL import Image

    from acroboter.report.animation.mujoco_frames import render_rows

    monkeypatch.setenv("MUJOCO_GL", gl)
    folder = _diverged_copy(results_2s, tmp_path, at=1.9)
    data = load(folder)
    rows = frame_rows(data.scene.t, 10.0, 1.0)[-2:]
    last = list(render_rows(data.scene, data.spec, rows, (320, 240), "penalty", note_from=1))
    plain = list(render_rows(data.scene, data.spec, rows, (320, 240), "penalty"))
    assert np.array_equal(last[0], plain[0])
    assert (np.abs(last[1].astype(int) - plain[1].astype(int)).max(axis=2) > 60).sum() > 50

    gif = tmp_path / "m.gif"
    assert animate.main([str(results_2s), "--renderer", "mujoco", "--gif", str(gif), "--no-mp4", "-q"]) == 0
    scene = load(results_2s).scene
    gif_rows = frame_rows(scene.t, 8.0, 2.5)
    frames = MujocoFrames(scene, data.spec, "penalty", (480, 360))  # the GIF's size: the same camera
    try:
        with Image.open(gif) as image:
            k = image.n_frames // 2
            image.seek(k)
            decoded = np.asarray(image.convert("RGB")).astype(int)
        row = int(gif_rows[k])
        lo, hi = scene.tension_range
        for c in range(len(scene.cables)):
            if scene.slack[row, c]:
                continue
            expected = 255 * np.array(colormaps["viridis"]((scene.tension[row, c] - lo) / (hi - lo))[:3])
            a, b = (_project(frames, p) for p in scene.ends[row, c])
            best = []
            for f in np.linspace(0.3, 0.7, 5):
                x, y = np.round(a + f * (b - a)).astype(int)
                window = decoded[y - 2 : y + 3, x - 2 : x + 3].reshape(-1, 3)
                best.append(window[np.abs(window - expected).sum(axis=1).argmin()])
            error = np.abs(np.median(best, axis=0) - expected).max()
            assert error < 40, (scene.cables[c], expected, best)
    finally:
        frames.close()
