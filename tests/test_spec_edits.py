"""acroboter.model.spec_edits: the edits the studies, tools and tests derive their cranes with, judged by what the
spec parser reads back from the edited text (not by the text itself)."""

import tomllib

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from acroboter.model.spec import Spec
from acroboter.model.spec_edits import with_path, with_winch_limits
from acroboter.process.locations import example_names, example_spec

finite = st.floats(-1.0, 1.0, allow_nan=False).map(lambda x: round(x, 6))


def parsed(text: str) -> Spec:
    """The spec the text states (the schema's reading; whether its path suits the crane is not asked here)."""
    return Spec.model_validate(tomllib.loads(text))


@pytest.mark.parametrize("name", example_names())
def test_every_winch_gets_the_limits_and_nothing_else_changes(name):
    text = example_spec(name).read_text()
    before = parsed(text)
    winches = [a for a in before.actuators if a.kind == "winch_tension"]
    if not winches:
        with pytest.raises(ValueError, match="winch_tension"):
            with_winch_limits(text, 30.0, 5.0)
        return
    after = parsed(with_winch_limits(text, 30.0, 5.0))
    for old, new in zip(before.actuators, after.actuators, strict=True):
        if old.kind == "winch_tension":
            assert new.limits == [5.0, 30.0]
        else:
            assert new == old
    assert after.model_copy(update={"actuators": before.actuators}) == before


@pytest.mark.parametrize("name", example_names())
def test_the_lower_limit_left_out_keeps_the_specs_own_or_zero(name):
    text = example_spec(name).read_text()
    before = {a.name: a.limits for a in parsed(text).actuators if a.kind == "winch_tension"}
    if not before:
        return
    after = {a.name: a.limits for a in parsed(with_winch_limits(text, 40.0)).actuators if a.kind == "winch_tension"}
    assert after == {k: [(v[0] if v is not None else 0.0), 40.0] for k, v in before.items()}


@settings(max_examples=25, deadline=None)
@given(points=st.lists(st.tuples(finite, finite, finite), min_size=2, max_size=6),
       yaw=st.one_of(st.none(), st.floats(-180.0, 180.0, allow_nan=False)))
@example(points=[(0.0, 0.0, 0.0), (0.0, 0.0, 0.1)], yaw=0.0)  # a yaw of 0 is a yaw, not "keep the spec's"
def test_the_path_read_back_is_the_one_written(points, yaw):
    text = example_spec("acroboter").read_text()
    before = parsed(text)
    after = parsed(with_path(text, points, yaw))
    assert [tuple(p) for p in after.path.waypoints] == [tuple(float(c) for c in p) for p in points]
    assert after.path.yaw_deg == (before.path.yaw_deg if yaw is None else yaw)
    assert after.actuators == before.actuators


def test_a_text_without_the_entry_is_refused_not_returned_unchanged():
    with pytest.raises(ValueError, match="waypoints"):
        with_path("[path]\nyaw_deg = 0.0\n", [[0, 0, 0], [0.1, 0, 0]])
    with pytest.raises(ValueError, match="yaw_deg"):
        with_path("[path]\nwaypoints = [\n  [0, 0, 0],\n]\n", [[0, 0, 0], [0.1, 0, 0]], yaw_deg=10.0)
    with pytest.raises(ValueError, match="winch_tension"):
        with_winch_limits("[[actuators]]\nkind = \"joint_torque\"\n", 30.0)
    two = '[[actuators]]\nkind = "winch_tension"\ncable = "L1"\n[[actuators]]\nkind = "winch_tension"\nname = "w"\n'
    with pytest.raises(ValueError, match="1 of 2 winch actuators have no cable"):  # not one winch of two edited
        with_winch_limits(two, 30.0)
    with pytest.raises(ValueError, match="spans lines"):
        with_winch_limits('[[actuators]]\nkind = "winch_tension"\ncable = "L1"\nlimits = [\n  5.0, 30.0]\n', 40.0)
    with pytest.raises(ValueError, match="no closing"):
        with_path("[path]\nwaypoints = [\n  [0, 0, 0],\n", [[0, 0, 0], [0.1, 0, 0]])


def test_an_edited_text_can_be_edited_again():
    text = example_spec("acroboter").read_text()
    lift = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.1]]
    once = with_path(with_winch_limits(text, 29.0, 24.0), [[0.0, 0.0, 0.0], [0.25, 0.0, 0.0]])
    twice = with_path(with_winch_limits(once, 29.0, 24.0), lift)
    assert twice == with_path(with_winch_limits(text, 29.0, 24.0), lift)
    end = 'cable = "L1"'  # a file whose last line is a winch's cable, without a newline
    edited = with_winch_limits(f'[[actuators]]\nkind = "winch_tension"\n{end}', 3.0)
    assert edited.endswith(f"{end}\nlimits = [0.0, 3.0]\n")
