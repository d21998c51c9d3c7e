"""Fuzzing the shipped specs: every mutation ends in a valid spec or a SpecError with a field path.

Numbers scaled to extremes (0, negative, tiny, huge, NaN, ±inf), fields dropped, list items
duplicated, names changed, types swapped: validation must say what is wrong and where, never raise
anything else. A mutated spec that validates must still give a layout and a nominal configuration
(everything that runs before code generation), so no later command meets an unchecked value.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from conftest import SHIPPED_NAMES, raw_spec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acroboter.model.layout import build_layout, nominal_coordinates
from acroboter.model.spec import SpecError, parse_spec

EXTREMES = [0.0, -1.0, 1e-300, 1e300, math.nan, math.inf, -math.inf, -1e9, 7]
SWAPS = ["text", True, [], {}, [1.0, 2.0], {"x": 1}]


def _paths(node, prefix=()):
    """Every (path, value) in a nested dict/list, the root excluded."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield (*prefix, key), value
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield (*prefix, i), value
            yield from _paths(value, (*prefix, i))


def _parent(data, path):
    node = data
    for part in path[:-1]:
        node = node[part]
    return node


@st.composite
def mutated_specs(draw):
    data = raw_spec(draw(st.sampled_from(SHIPPED_NAMES)))
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(data))
        if not paths:
            break
        path, value = paths[draw(st.integers(0, len(paths) - 1))]
        parent, key = _parent(data, path), path[-1]
        kind = draw(st.sampled_from(["extreme", "scale", "drop", "duplicate", "rename", "swap"]))
        if kind == "extreme" or (kind == "scale" and not isinstance(value, (int, float))):
            parent[key] = draw(st.sampled_from(EXTREMES))
        elif kind == "scale" and not isinstance(value, bool):
            parent[key] = value * draw(st.sampled_from([1e-9, 1e-3, -1.0, 1e3, 1e9]))
        elif kind == "drop":
            del parent[key]
        elif kind == "duplicate" and isinstance(parent, list):
            parent.insert(key, copy.deepcopy(parent[key]))
        elif kind == "rename" and isinstance(value, str):
            parent[key] = draw(st.sampled_from([value + "_x", "", "9lives", "a" * 80, "CC", "SU.b1", "climbing_unit"]))
        else:
            parent[key] = copy.deepcopy(draw(st.sampled_from(SWAPS)))  # never share (or nest) a mutable
    return data


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_specs())
def test_every_mutation_is_valid_or_a_spec_error_with_a_path(data):
    try:
        spec = parse_spec(data, "fuzzed.toml")
    except SpecError as err:
        assert err.problems, "a SpecError lists its problems"
        for path, message in err.problems:
            assert isinstance(path, str) and path and isinstance(message, str) and message
        return
    layout = build_layout(spec)
    q0 = nominal_coordinates(spec, layout)
    assert np.isfinite(q0).all()
    lower, upper, preferred = spec.input_limits()
    assert (lower < upper).all() and not np.isnan(preferred).any()
    assert len(spec.model_hash()) == 64
