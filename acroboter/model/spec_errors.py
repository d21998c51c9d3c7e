"""Pydantic's validation errors as the spec's own problems: `path: expected …, found …`, with TOML's type
names and the keys a table knows."""

from __future__ import annotations

import types
from typing import Annotated, Any, Union, get_args, get_origin

from pydantic import BaseModel, ValidationError

from .schema import (
    ACTUATOR_KINDS,
    NAME_PATTERN,
    TASK_KINDS,
    Spec,
)
from .spec_checks import listing

_TOML_TYPES = {str: "a string", bool: "a boolean", int: "an integer", float: "a float", list: "an array",
               dict: "a table"}


def _found(value: Any) -> str:
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    kind = next((name for t, name in _TOML_TYPES.items() if type(value) is t), type(value).__name__)
    return f"{text} ({kind})"


def _clean_loc(loc: tuple, data: Any) -> list:
    """Drop union-branch tags from a pydantic location by walking the input along it."""
    parts, node = [], data
    for k, part in enumerate(loc):
        if isinstance(node, dict) and isinstance(part, str):
            if part in node:
                node = node[part]
            elif k < len(loc) - 1:
                continue  # a branch tag such as 'winch_tension' or 'polar'
            else:
                node = None  # the missing or unknown key itself
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        elif isinstance(node, list):
            continue  # a branch tag inside a list value ('xyz')
        parts.append(part)
    return parts


def _format_loc(parts: list, data: Any = None) -> str:
    loc = ""
    for k, part in enumerate(parts):
        loc += f"[{part}]" if isinstance(part, int) else (f".{part}" if loc else str(part))
        # name the actuator, as the cross-field checks do: actuators[0] (tension_1).limits
        if k == 1 and parts[0] == "actuators" and isinstance(part, int) and len(parts) > 2 and isinstance(data, dict):
            items = data.get(parts[0])
            item = items[part] if isinstance(items, list) and 0 <= part < len(items) else None
            if isinstance(item, dict) and isinstance(item.get("name"), str):
                loc += f" ({item['name']})"
    return loc or "(top level)"


def _strip(tp: Any, node: Any) -> Any:
    """The concrete type a value `node` is validated as: unwrap Annotated and pick the union member."""
    while True:
        origin = get_origin(tp)
        if origin is Annotated:
            tp = get_args(tp)[0]
        elif origin in (Union, types.UnionType):
            members = [_strip(m, node) for m in get_args(tp) if m is not type(None)]
            models = [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]
            if isinstance(node, dict) and models:
                tagged = [m for m in models if "kind" in m.model_fields
                          and node.get("kind") in get_args(m.model_fields["kind"].annotation)]
                return (tagged or models)[0]
            return members[0]
        else:
            return tp


def _known_keys(parts: list, data: Any) -> list[str]:
    """Field names of the table at `parts` (the location of an unknown key, without the key)."""
    tp, node = Spec, data
    try:
        for part in parts:
            tp = _strip(tp, node)
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                tp = tp.model_fields[part].annotation
            else:  # list[...] or dict[str, ...]: the item type is the last argument
                tp = get_args(tp)[-1]
            node = node[part]
        tp = _strip(tp, node)
        return list(tp.model_fields) if isinstance(tp, type) and issubclass(tp, BaseModel) else []
    except (KeyError, IndexError, TypeError, AttributeError):
        return []


def _describe(e: dict, parts: list, data: Any) -> tuple[list, str]:
    """(location parts, 'expected …, found …') for one pydantic error."""
    kind, ctx, value = e["type"], e.get("ctx", {}), e.get("input")
    if kind == "missing":
        return parts, "expected this required field, found it missing"
    if kind == "extra_forbidden":
        known = _known_keys(parts[:-1], data)
        return parts, f"expected one of the known keys ({', '.join(known)}), found unknown key '{parts[-1]}'"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        field = ctx.get("discriminator", "'kind'").strip("'")
        kinds = {"actuators": ACTUATOR_KINDS, "task": TASK_KINDS}.get(parts[0] if parts else "", ())
        expected = f"one of {listing(kinds)}" if kinds else f"one of {ctx.get('expected_tags', '?')}"
        if kind == "union_tag_not_found" or not isinstance(value, dict) or field not in value:
            return [*parts, field], f"expected this required field ({expected}), found it missing"
        return [*parts, field], f"expected {expected}, found {_found(value[field])}"
    return parts, _value_problem(kind, e, ctx, value)


_TYPE_WORDS = {"string_type": "a string", "bool_type": "true or false", "list_type": "an array", "dict_type": "a table",
               "model_type": "a table", "model_attributes_type": "a table"}
_BOUND_WORDS = {"greater_than": ("greater than", "gt"), "greater_than_equal": ("at least", "ge"),
                "less_than": ("less than", "lt"), "less_than_equal": ("at most", "le")}


def _value_problem(kind: str, e: dict, ctx: dict, value: Any) -> str:
    """'expected …, found …' for an error in a value (its type, range, form or length)."""
    if kind == "literal_error":
        return f"expected one of {ctx['expected']}, found {_found(value)}"
    if kind in ("float_type", "float_parsing", "int_type", "int_parsing", "int_from_float"):
        what = "an integer" if kind.startswith("int") else "a number"
        return f"expected {what}, found {_found(value)}"
    if kind in ("number_range", "value_error", "wrong_length", "point_form"):
        return _own_words(kind, e, ctx, value)
    if kind == "finite_number":
        return f"expected a finite number, found {_found(value)}"
    if kind in _BOUND_WORDS:
        words, key = _BOUND_WORDS[kind]
        return f"expected a number {words} {ctx[key]}, found {value!r}"
    if kind in _TYPE_WORDS:
        return f"expected {_TYPE_WORDS[kind]}, found {_found(value)}"
    if kind == "string_pattern_mismatch" and ctx.get("pattern") == NAME_PATTERN:
        return f"expected a name of letters, digits and '_' that does not start with a digit, found {_found(value)}"
    if kind == "string_too_long":
        return f"expected at most {ctx['max_length']} characters, found {len(value)}: {_found(value)}"
    if kind in ("too_short", "too_long"):
        limit = f"at least {ctx['min_length']}" if kind == "too_short" else f"at most {ctx['max_length']}"
        return f"expected {limit} item(s), found {ctx.get('actual_length', len(value))}: {_found(value)}"
    msg = e["msg"]
    return f"expected {msg[0].lower() + msg[1:]}, found {_found(value)}"


def _own_words(kind: str, e: dict, ctx: dict, value: Any) -> str:
    """The errors the schema's own validators raise, whose message already says what was expected."""
    if kind == "number_range":  # a Range's own words (acroboter.model.ranges): expected 0 < kp <= 1e4 (1/s), found …
        return e["msg"]
    if kind == "value_error":
        return str(ctx.get("error", e["msg"]))
    return f"{e['msg']}: {_found(value)}" if kind == "wrong_length" else f"{e['msg']}, found {_found(value)}"


def format_pydantic(err: ValidationError, data: Any) -> list[tuple[str, str]]:
    problems: list[tuple[str, str]] = []
    for e in err.errors(include_url=False):
        parts = _clean_loc(e["loc"], data)
        parts, text = _describe(e, parts, data)
        problem = (_format_loc(parts, data), text)
        if problem not in problems:
            problems.append(problem)
    return problems
