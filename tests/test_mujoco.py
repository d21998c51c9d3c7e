"""The project's plant against MuJoCo, an engine written by others, on the spec's MJCF model.

Oracles: MuJoCo (mujoco, pinned) stepping the XML of acroboter.model.mjcf_model, analytic statics (each
winch of the symmetric crane carries m_SU g L / (3 drop)) and ballistics (the centre of mass of
bodies on slack cables falls at g). Nothing here compares the code with numbers it produced before.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

try:
    import mujoco
except ImportError:  # the mujoco extra is not installed: every test here is skipped (needs_mujoco)
    mujoco = None

from acroboter import Crane
from acroboter.control.path import TrajectoryPath
from acroboter.model.mjcf_model import MjcfError, check_representable, joint_layout, mjcf_xml
from acroboter.model.spec import BodyThrust, BodyTorque, WinchTension, load_spec
from acroboter.sim.mujoco_plant import MujocoPlant
from acroboter.sim.plant import Plant

pytestmark = pytest.mark.needs_mujoco

ROOT = Path(__file__).resolve().parent.parent
SPECS = sorted((ROOT / "model_spec").glob("*.toml"))
AGREEMENT_M = 20e-6  # the bound on positions and winch lengths, m


@pytest.fixture(scope="module")
def cranes():
    return {path.stem: Crane.from_toml(path) for path in SPECS}


# --- the XML --------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.stem)
def test_checked_in_mjcf_is_what_the_writer_makes_and_loads(path):
    spec = load_spec(path)
    xml_file = ROOT / "generated" / spec.name / f"{spec.name}.xml"
    assert xml_file.read_text() == mjcf_xml(spec) == mjcf_xml(load_spec(path))  # deterministic, checked in
    model = mujoco.MjModel.from_xml_path(str(xml_file))
    # The spec's crane, part by part.
    for body in spec.bodies:
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body.name)
        assert model.body_mass[b] == body.mass
        assert np.allclose(np.sort(model.body_inertia[b]), np.sort(np.linalg.eigvalsh(np.array(body.inertia))),
                           rtol=1e-12)
        assert np.allclose(model.body_ipos[b], 0.0)  # the body frame is the centre of mass
    assert [model.actuator(i).name for i in range(model.nu)] == [a.name for a in spec.actuators]
    for i, act in enumerate(spec.actuators):
        low, high = act.resolved_limits()
        assert tuple(model.actuator_ctrlrange[i]) == (low, high) or not model.actuator_ctrllimited[i]
        gear = model.actuator_gear[i]
        if isinstance(act, WinchTension):
            assert gear[0] == -act.gain  # pulls the length in
        elif isinstance(act, BodyThrust):
            assert np.count_nonzero(gear[:3]) == 1 and not gear[3:].any()
        elif isinstance(act, BodyTorque):
            assert np.count_nonzero(gear[3:]) == 1 and not gear[:3].any()
    for cable in spec.cables:
        if cable.length is not None:
            t = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TENDON, cable.name)
            assert model.tendon_limited[t] and model.tendon_range[t, 1] == cable.length


def test_the_library_face_gives_the_same_xml(cranes):
    import acroboter

    crane = cranes["acroboter"]
    assert crane.mjcf() == acroboter.mjcf_xml(crane.spec) == (ROOT / "generated/acroboter/acroboter.xml").read_text()
    heavier = mujoco.MjModel.from_xml_string(crane.mjcf(timestep=5e-4, plant_params={"SU.mass": 8.8}))
    assert heavier.opt.timestep == 5e-4
    assert heavier.body_mass[mujoco.mj_name2id(heavier, mujoco.mjtObj.mjOBJ_BODY, "SU")] == 8.8


def test_mjcf_command_writes_a_loadable_file_and_refuses_bad_specs(tmp_path):
    out = tmp_path / "crane.xml"
    ok = subprocess.run([sys.executable, "-m", "acroboter.mjcf", str(SPECS[0]), "-o", str(out)],
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert mujoco.MjModel.from_xml_path(str(out)).nu == len(load_spec(SPECS[0]).actuators)
    text = (ROOT / "model_spec" / "acroboter.toml").read_text()
    cases = {
        "same_point": (text.replace('ends = ["CC.a1", "SU.b1"]', 'ends = ["CC.a1", "CC.a1"]'), "cables[1] (L1)"),
        "bad_actuator": (text.replace('cable = "L1"', 'cable = "main"'), "actuators[0] (tension_1)"),
        "no_body": (text.replace('body = "SU"\naxis = "w"', 'body = "XX"\naxis = "w"', 1), "actuators[3]"),
    }
    for name, (spec_text, named) in cases.items():
        assert spec_text != text, name
        bad = tmp_path / f"{name}.toml"
        bad.write_text(spec_text.replace('name = "acroboter"', f'name = "{name}"', 1))
        proc = subprocess.run([sys.executable, "-m", "acroboter.mjcf", str(bad), "-o", str(tmp_path / "x.xml")],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 2, (name, proc.stderr)
        assert named in proc.stderr and "Traceback" not in proc.stderr, (name, proc.stderr)
        assert not (tmp_path / "x.xml").exists()


def test_mjcf_command_writes_the_static_start_with_a_keyframe_that_holds_it(tmp_path):
    out = tmp_path / "static.xml"
    proc = subprocess.run([sys.executable, "-m", "acroboter.mjcf", str(SPECS[0]), "-o", str(out), "-q"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert out.stat().st_mode & 0o777 == 0o666 & ~_umask()  # an ordinary new file, not mkstemp's 0600
    model = mujoco.MjModel.from_xml_path(str(out))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("static_start").id)
    mujoco.mj_forward(model, data)
    su = model.body("SU").id
    before = data.xpos[su].copy()
    mujoco.mj_step(model, data, 10_000)  # 1 s in MuJoCo alone, the keyframe's inputs held
    assert np.abs(data.xpos[su] - before).max() < 1e-6
    spec = subprocess.run([sys.executable, "-m", "acroboter.mjcf", str(SPECS[0]), "--pose", "spec", "-o", "-"],
                          capture_output=True, text=True, timeout=300)
    assert spec.stdout == (ROOT / "generated" / "acroboter" / "acroboter.xml").read_text()


def test_mjcf_warns_like_run_when_the_static_start_needs_an_input_beyond_its_limits(tmp_path, capsys):
    """Winches capped at 26 N where the static start needs 26.75 N (limits need no regeneration): the XML is
    written (exit 0) with a warning on stderr, also with -q, naming the input, the need and the limit, as
    `acroboter run`'s feasibility check at t = 0 does."""
    import re

    from acroboter.cli import mjcf

    text = re.sub(r'(kind = "winch_tension".*\ncable = "L\d")', lambda m: f"{m.group(1)}\nlimits = [0.0, 26.0]",
                  SPECS[0].read_text())
    assert text.count("limits = [0.0, 26.0]") == 3
    spec_path = tmp_path / "capped.toml"
    spec_path.write_text(text)
    out = tmp_path / "capped.xml"
    assert mjcf.main([str(spec_path), "-o", str(out), "-q"]) == 0
    captured = capsys.readouterr()
    assert captured.out == "" and out.is_file()
    warnings = [line for line in captured.err.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 3, captured.err  # the three winches
    for line in warnings:
        assert "the static start is outside the input limits" in line and "would need 26.75 N" in line
        assert "beyond its limit 26 N" in line and "MuJoCo clamps" in line
    model = mujoco.MjModel.from_xml_path(str(out))
    assert np.all(model.key("static_start").ctrl[:3] > model.actuator_ctrlrange[:3, 1])  # what the warning says
    assert mjcf.main([str(SPECS[0]), "-o", str(out), "-q"]) == 0  # within the limits: no warning
    assert "warning" not in capsys.readouterr().err


def test_a_static_start_that_needs_a_winch_to_push_is_named():
    from acroboter.model.layout import build_layout
    from acroboter.sim.statics import inputs_outside_limits

    spec = load_spec(SPECS[0])
    layout = build_layout(spec)
    inputs = np.zeros(layout.l)
    inputs[:3] = 26.75
    assert inputs_outside_limits(spec, layout, inputs) == []
    inputs[1] = -3.25
    assert inputs_outside_limits(spec, layout, inputs) == [
        "tension_2 would need -3.25 N, beyond its limit 0 N (a winch cannot push)"]


def _umask() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.mark.parametrize("target, message", [
    ("/nonexistent-folder/x.xml", "does not exist"),
    ("/dev/null", "an MJCF file is named *.xml"),
])
def test_mjcf_command_refuses_outputs_it_cannot_write_before_any_work(target, message):
    proc = subprocess.run([sys.executable, "-m", "acroboter.mjcf", str(SPECS[0]), "-o", target],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


def test_a_fixed_cable_whose_ends_meet_is_refused():
    spec = load_spec(SPECS[0])
    anchor = spec.anchors[0]
    top = spec.body("CC")
    # the climbing unit exactly at the CC's top point: the main cable has no direction at qpos0
    moved = spec.model_copy(deep=True)
    moved.anchors[0] = anchor.model_copy(update={"position": [top.initial_position[0], top.initial_position[1],
                                                              top.initial_position[2] + top.point("top")[2]]})
    with pytest.raises(MjcfError, match=r"cables\[0\] \(main\)"):
        check_representable(moved)


# --- statics: MuJoCo holds the model's equilibrium with the model's tensions ------------------------


def test_mujoco_holds_the_static_start_with_the_analytic_tensions(cranes):
    crane = cranes["acroboter"]
    spec, lay = crane.spec, crane.layout
    start = crane.equilibrium()
    plant = MujocoPlant(crane.model, crane.path)
    x = plant.initial_state(start.q)
    h = spec.simulation.step
    for _ in range(50):  # 1 s with the static inputs, the path (and the climbing unit) held at its start
        plant.advance(x, start.inputs, h, plant.stage_table(0.0, h, 10), 0, 10)
    drift = np.abs(x[: lay.n] - start.q).max()
    assert drift < 1e-7
    su = spec.body("SU")
    length = start.q[lay.winch_index["L1"]]
    drop = (start.q[lay.body_offset["CC"] + 2] + spec.body("CC").point("a1")[2]) - (
        start.q[lay.body_offset["SU"] + 2] + su.point("b1")[2])
    analytic = su.mass * 9.81 * length / (3 * drop)
    assert plant.start_tension[1:] == pytest.approx([analytic] * 3, rel=1e-6)
    total = (su.mass + spec.body("CC").mass) * 9.81
    assert plant.start_tension[0] == pytest.approx(total, rel=1e-6)  # the main cable carries both bodies


# --- dynamics: 5 s of open-loop inputs, own plant against MuJoCo ----------------------------------------


def _anchor_motion(start_point, duration, displacement):
    displacement = np.asarray(displacement, dtype=float)

    def motion(t):
        tau = np.clip(np.asarray(t, dtype=float) / duration, 0.0, 1.0)
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        ds = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / duration
        dds = (60 * tau - 180 * tau**2 + 120 * tau**3) / duration**2
        return start_point + np.outer(s, displacement), np.outer(ds, displacement), np.outer(dds, displacement)

    return motion


def open_loop(crane, duration=5.0, timestep=1e-4):
    """Both plants from the static start under the same inputs (each input excited around its static
    value, held per control period) while the moving anchor travels 9.4 cm."""
    spec, lay = crane.spec, crane.layout
    start = crane.equilibrium()
    motion = _anchor_motion(crane.path.position(0.0)[0], duration, [0.08, -0.05, 0.0])
    path = TrajectoryPath(spec, lay, motion, duration, crane.path.start_yaw)
    own = Plant(crane.model, path, spec.simulation.baumgarte_zeta, spec.simulation.baumgarte_omega)
    engine = MujocoPlant(crane.model, path, timestep=timestep)
    x, y = own.initial_state(start.q), engine.initial_state(start.q)
    period, h = 1.0 / spec.controller.rate_hz, spec.simulation.step
    substeps = round(period / h)
    amplitude = np.where(np.abs(start.inputs) > 1.0, 0.15 * np.abs(start.inputs), 0.3)  # N or N·m
    frequency = 0.3 + 0.17 * np.arange(lay.l)  # Hz, a different one per input
    steps = int(round(duration / period))
    own_q, mj_q, inputs = np.zeros((steps + 1, lay.n)), np.zeros((steps + 1, lay.n)), np.zeros((steps, lay.l))
    own_q[0], mj_q[0] = start.q, start.q
    for k in range(steps):
        t = k * period
        u = start.inputs + amplitude * np.sin(2 * np.pi * frequency * t) * min(1.0, t)
        inputs[k] = u
        own.advance(x, u, h, own.stage_table(t, h, substeps), 0, substeps)
        engine.advance(y, u, h, engine.stage_table(t, h, substeps), 0, substeps)
        own_q[k + 1], mj_q[k + 1] = x[: lay.n], y[: lay.n]
    return start, own, engine, own_q, mj_q, inputs


@pytest.mark.parametrize("name", [p.stem for p in SPECS])
def test_open_loop_motion_agrees_with_mujoco(cranes, name):
    crane = cranes[name]
    lay = crane.layout
    start, own, engine, own_q, mj_q, inputs = open_loop(crane)
    # Rich: every input moved by its amplitude, the bodies swing and turn, the winches reel.
    assert (np.ptp(inputs, axis=0) > 0.2).all()
    su = lay.body_offset[next(t.body for t in crane.spec.task if t.kind == "position")]
    assert np.linalg.norm(own_q[-1, su : su + 3] - start.q[su : su + 3]) > 0.1
    for cable, i in lay.winch_index.items():
        assert np.ptp(own_q[:, i]) > 5e-3, cable
    assert not own.transitions.any() and not engine.transitions.any()  # the cables stayed taut in both
    # Agreement: centres of the bodies and winch lengths within 20 µm at every control instant.
    for body in crane.spec.bodies:
        i = lay.body_offset[body.name]
        gap = np.linalg.norm(own_q[:, i : i + 3] - mj_q[:, i : i + 3], axis=1).max()
        assert gap < AGREEMENT_M, f"{name}: {body.name} differs by {gap * 1e6:.2f} µm"
        axes = np.abs(own_q[:, i + 3 : i + 12] - mj_q[:, i + 3 : i + 12]).max()
        assert axes < 1e-4, f"{name}: {body.name}'s axes differ by {axes:.2e}"
    for cable, i in lay.winch_index.items():
        gap = np.abs(own_q[:, i] - mj_q[:, i]).max()
        assert gap < AGREEMENT_M, f"{name}: winch {cable} differs by {gap * 1e6:.2f} µm"
    assert engine.start_tension == pytest.approx(own.start_tension, rel=1e-4)


def test_a_slack_cable_falls_and_snaps_taut_in_both_plants(cranes):
    """Both bodies lifted 5 mm with the main cable slack and no damping: their centre of mass falls
    at g (ballistics) until the cable reaches its length, then both plants carry on together."""
    crane = cranes["acroboter"]
    spec, lay = crane.spec, crane.layout
    start = crane.equilibrium()
    q = start.q.copy()
    for body in spec.bodies:
        q[lay.body_offset[body.name] + 2] += 5e-3
    undamped = {f"{b.name}.damping.{kind}": 0.0 for b in spec.bodies for kind in ("translational", "rotational")}
    own = Plant(crane.model, crane.path, spec.simulation.baumgarte_zeta, spec.simulation.baumgarte_omega, undamped)
    engine = MujocoPlant(crane.model, crane.path, undamped)
    x, y = own.initial_state(q), engine.initial_state(q)
    assert own.start_active[0] == 0.0  # the own plant starts the slack cable slack (it used to pull it taut)
    masses = np.array([b.mass for b in spec.bodies])
    offsets = [lay.body_offset[b.name] for b in spec.bodies]

    def centre_z(state):
        return float(masses @ np.array([state[i + 2] for i in offsets]) / masses.sum())

    h, period = spec.simulation.step, 0.02
    z0 = centre_z(q)
    t = 0.0
    falling = True
    worst = 0.0
    for k in range(50):
        own.advance(x, start.inputs, h, own.stage_table(t, h, 10), 0, 10)
        engine.advance(y, start.inputs, h, engine.stage_table(t, h, 10), 0, 10)
        t += period
        if falling and own.start_active[0] == 0.0 and k == 0:  # still slack over the first period
            assert centre_z(x) == pytest.approx(z0 - 0.5 * 9.81 * t**2, abs=1e-12)
            assert centre_z(y) == pytest.approx(z0 - 0.5 * 9.81 * t**2, abs=1e-9)
        for i in offsets:
            worst = max(worst, float(np.linalg.norm(x[i : i + 3] - y[i : i + 3])))
    assert own.transitions[0] >= 1 and engine.transitions[0] >= 1  # it went taut in both
    assert worst < AGREEMENT_M, f"after the snap the plants differ by {worst * 1e6:.2f} µm"


# --- closed loop: the controllers drive MuJoCo as they drive their own plant ----------------------------


@pytest.mark.parametrize("method", ["mlm", "penalty"])
def test_closed_loop_on_mujoco_tracks_the_default_scenario_as_on_the_own_plant(cranes, method):
    crane = cranes["acroboter"]
    own = crane.simulate(method, warm_up=0)
    engine = crane.simulate(method, warm_up=0, plant="mujoco")
    assert engine.diverged_at is None
    own_max, mj_max = own.position_error_mm.max(), engine.position_error_mm.max()
    assert abs(mj_max - own_max) <= 0.1 * own_max, (own_max, mj_max)
    assert np.abs(engine.position - own.position).max() < AGREEMENT_M
    assert engine.summary()["cables"]["main"]["time_slack_s"] == 0.0


def test_mujoco_timestep_must_divide_the_plant_step(cranes):
    crane = cranes["acroboter"]
    with pytest.raises(ValueError, match=r"must divide .* give e.g. 0.00025 s"):
        crane.simulate("mlm", duration=0.1, plant="mujoco", mujoco_timestep=3e-4)
    assert crane.simulate("mlm", duration=0.02, plant="mujoco", mujoco_timestep=2.5e-4).diverged_at is None
    with pytest.raises(ValueError, match="only the MuJoCo plant"):
        crane.simulate("mlm", duration=0.1, mujoco_timestep=1e-4)
    with pytest.raises(ValueError, match="plant: expected"):
        crane.simulate("mlm", duration=0.1, plant="bullet")


def test_an_input_beyond_its_limits_is_refused_not_clipped(cranes):
    from acroboter.sim.plant import SimulationError

    crane = cranes["acroboter"]
    start = crane.equilibrium()
    plant = MujocoPlant(crane.model, crane.path)
    x = plant.initial_state(start.q)
    pushing = start.inputs.copy()
    pushing[0] = -5.0  # a winch that pushes: MuJoCo's ctrlrange [0, inf] would clip it to 0 silently
    h = crane.spec.simulation.step
    with pytest.raises(SimulationError, match=r"tension_1 = -5 N is beyond its limits \[0, inf\]"):
        plant.advance(x, pushing, h, plant.stage_table(0.0, h, 10), 0, 10)


def test_a_mujoco_step_that_does_not_divide_is_refused_before_any_work(tmp_path):
    out = tmp_path / "never"
    proc = subprocess.run([sys.executable, "-m", "acroboter.run", "--plant", "mujoco", "--mujoco-timestep", "0.0003",
                           "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "give e.g. 0.00025 s" in proc.stderr, proc.stderr
    assert not out.exists()


def test_run_with_the_mujoco_plant_writes_the_same_folder(tmp_path):
    out = tmp_path / "mj"
    out.mkdir()
    (out / "animation_penalty.mp4").write_bytes(b"a video of the user's")  # no manifest lists it: it stays
    proc = subprocess.run([sys.executable, "-m", "acroboter.run", "--plant", "mujoco", "--method", "penalty",
                           "--duration", "2", "--out", str(out), "-q"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "plant MuJoCo" in proc.stdout
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["provenance"]["plant"]["engine"] == "mujoco"
    assert summary["provenance"]["plant"]["mujoco_version"] == mujoco.__version__
    assert {"penalty.csv", "summary.json", "tracking_errors.png", "path_3d.png"} <= {p.name for p in out.iterdir()}
    assert (out / "animation_penalty.mp4").read_bytes() == b"a video of the user's"  # docs/run.md
    assert "cold cache" in proc.stdout  # the step times are not the controllers' warm ones


@pytest.mark.parametrize("display, message", [(None, "needs a display"), (":987", "GLFW could not open a window")])
def test_view_without_a_display_says_so_before_any_work(tmp_path, display, message):
    import os

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if display:
        env["DISPLAY"] = display  # set, but no X server answers there (ssh without forwarding)
    proc = subprocess.run([sys.executable, "-m", "acroboter.run", "--view", "--out", str(tmp_path / "v")],
                          capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 3
    assert message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert not (tmp_path / "v").exists()


@pytest.mark.needs_display
def test_view_replays_the_run_in_mujocos_viewer_on_a_virtual_display(tmp_path):
    """Where Xvfb is installed (not on CI's machine: skipped there): the viewer opens and replays."""
    import os
    import shutil
    import signal
    import time

    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not installed (apt-get install xvfb): no display to open the viewer on")
    out = tmp_path / "viewed"
    proc = subprocess.Popen(["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", sys.executable, "-m", "acroboter.run",
                             "--method", "mlm", "--duration", "1", "--view", "--out", str(out), "-q"],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        deadline, seen = time.monotonic() + 120, ""
        while time.monotonic() < deadline and "viewer: mlm" not in seen:
            line = proc.stderr.readline()
            if not line and proc.poll() is not None:
                break
            seen += line
        assert "viewer: mlm (1.0 s)" in seen, seen
        assert (out / "mlm.csv").is_file()  # the results were written before the window opened
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # the viewer stays open until its window is closed
        proc.wait(timeout=300)


def test_a_heavier_load_on_mujoco_sags_as_on_the_own_plant(cranes):
    """SU and CC 10 % heavier in MuJoCo's crane than in the controller's model (plant_params write the
    XML from the perturbed spec), a 4 s hold at the start: the same steady sag as the own plant's,
    which tests/test_plant_mismatch.py derives (38.5 mm, Δm_SU g / (m_eff k_P²))."""
    from test_plant_mismatch import hold as hold_at_start  # the hold that test derives the sag for

    crane = cranes["acroboter"]
    hold = hold_at_start(crane, 4.0)
    heavier = {"SU.mass": 1.1 * crane.spec.body("SU").mass, "CC.mass": 1.1 * crane.spec.body("CC").mass}
    runs = {plant: crane.simulate("penalty", trajectory=hold, duration=4.0, warm_up=0, plant_params=heavier,
                                  plant=plant) for plant in ("own", "mujoco")}
    sag = {plant: -r.run.sigma[r.time >= 3.5, 2].mean() for plant, r in runs.items()}
    assert sag["own"] == pytest.approx(0.0385, abs=5e-4)
    assert abs(sag["mujoco"] - sag["own"]) < AGREEMENT_M, sag


def test_yawed_bodies_on_slide_and_ball_joints_agree_too():
    """lab_crane's bodies (damping that differs: slides and a ball joint) turned at the start, so the
    body frames at qpos0 are not the world's: the state mapping in both directions is exercised."""
    from acroboter.model.spec import Spec

    data = load_spec(ROOT / "model_spec" / "lab_crane.toml").model_dump()
    data["name"] = "lab_crane_yawed"
    for body in data["bodies"]:
        body["initial_yaw_deg"] = 30.0 if body["name"] == "SU" else 20.0
    crane = Crane.from_spec(Spec.model_validate(data))
    assert set(joint_layout(crane.spec).values()) == {"slide+ball"}
    _, own, engine, own_q, mj_q, _ = open_loop(crane)
    for body in crane.spec.bodies:
        i = crane.layout.body_offset[body.name]
        assert np.linalg.norm(own_q[:, i : i + 3] - mj_q[:, i : i + 3], axis=1).max() < AGREEMENT_M
        assert np.abs(own_q[:, i + 3 : i + 12] - mj_q[:, i + 3 : i + 12]).max() < 1e-6
