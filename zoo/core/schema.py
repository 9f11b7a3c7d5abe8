"""The zoo's YAML files read through one schema library, pydantic: a file's data validated
against a type (a pydantic dataclass, a TypedDict), each refusal one line naming the file, the
line, the field and what was expected.

pydantic, not checks of our own: the types say each field once (the dataclass a file fills is
its schema), unknown and missing fields, unions by a tag and numeric bounds come with it, and
each error carries its field's path, which :func:`problem` turns into the file's line.
"""

# zoo: computes no number

from __future__ import annotations

import difflib
import functools
import math
import typing
from pathlib import Path
from typing import Any

import pydantic
import typing_extensions
import yaml

from zoo.core.errors import ZooError


class SchemaError(ZooError, ValueError):
    """A YAML file's field that its schema refuses; the message names the file and line."""


@functools.cache
def _adapter(type_: Any) -> pydantic.TypeAdapter:
    return pydantic.TypeAdapter(type_)


def validated(
    type_: Any,
    data: Any,
    path: Path | None = None,
    at: tuple = (),
    what: str = "",
    error: type[Exception] = SchemaError,
) -> Any:
    """``data`` as ``type_``. It was read from ``path`` under the keys ``at`` (a registry's
    ``("models", "ltd", "train")``); ``what`` starts the message after the file and line
    (``model 'ltd': ``); a refusal raises ``error`` with :func:`problem`'s line."""
    try:
        return _adapter(type_).validate_python(data)
    except pydantic.ValidationError as e:
        raise error(problem(e, type_, data, path, at, what)) from None


def problem(
    e: pydantic.ValidationError,
    type_: Any,
    data: Any,
    path: Path | None,
    at: tuple = (),
    what: str = "",
) -> str:
    """The first of ``e``'s errors in one line: ``FILE, line N: WHAT field 'a.b': expected ...,
    got ...`` (no file where the data came from no file: a command line's options)."""
    errors = e.errors(include_url=False)
    # a misspelt field first: the field it was meant for is then missing too
    first = min(errors, key=lambda err: err["type"] not in _UNKNOWN)
    loc = tuple(first["loc"])
    field = ".".join(str(k) for k in _written(data, loc))
    kind, message = first["type"], first["msg"]
    if kind == "missing":
        said = f"field {field!r} is required"
    elif kind in _UNKNOWN:
        valid = _field_names(type_, loc[:-1])
        close = difflib.get_close_matches(str(loc[-1]), valid, n=1, cutoff=0.6)
        said = (
            f"unknown field {field!r}"
            + (f" (did you mean {close[0]!r}?)" if close else "")
            + (f"; valid fields: {', '.join(valid)}" if valid else "")
        )
    else:
        message = message.removeprefix("Value error, ").removeprefix("Assertion failed, ")
        expected = message[:1].lower() + message[1:]
        got = "" if kind == "value_error" else f", got {first['input']!r}"
        if kind == "float_type" and _reads_as_number(first["input"]):
            got += f" (YAML reads {first['input']} as text: write it with a point, 3.0e-4)"
        said = f"field {field!r}: {expected}{got}" if field else f"{expected}{got}"
    where = f"{path}" if path is not None else ""
    line = line_of(path, (*at, *loc)) if path is not None else None
    if line is not None:
        where += f", line {line}"
    return f"{where}: {what}{said}" if where else f"{what}{said}"


_UNKNOWN = ("extra_forbidden", "unexpected_keyword_argument")


def _reads_as_number(value: Any) -> bool:
    try:
        return isinstance(value, str) and math.isfinite(float(value))
    except ValueError:
        return False


def _written(data: Any, loc: tuple) -> list:
    """The keys of ``loc`` that the data writes: not the union member's tag pydantic puts in an
    error's path (a schedule's ``step`` in ``schedule.step.gamma``)."""
    keys = []
    for i, key in enumerate(loc):
        if isinstance(data, dict) and key in data:
            data = data[key]
        elif isinstance(data, (list, tuple)) and isinstance(key, int) and key < len(data):
            data = data[key]
        elif i < len(loc) - 1 or isinstance(key, int):
            continue  # a tag, or the item pydantic made of one value where a list may be
        keys.append(key)
    return keys


def _field_names(type_: Any, loc: tuple) -> list[str]:
    """The fields a file may write at ``loc`` inside ``type_`` (its aliases where it has them),
    for a refusal of an unknown one; empty where it cannot be told."""
    for key in loc:
        fields = _fields_of(type_)
        if key in fields:
            type_ = fields[key]
            continue
        members = [m for m in _members(type_) if _tag_of(m) == key]
        if not members:
            return []
        type_ = members[0]
    return sorted(_fields_of(type_))


def _members(type_: Any) -> tuple:
    """A union's (or an Annotated union's, an optional one's) member types."""
    while typing.get_origin(type_) is typing.Annotated:
        type_ = typing.get_args(type_)[0]
    return typing.get_args(type_)


def _tag_of(type_: Any) -> Any:
    """A union member's tag: the one value its ``type`` field may hold."""
    tag = typing.get_args(_fields_of(type_).get("type"))
    return tag[0] if len(tag) == 1 else None


def _fields_of(type_: Any) -> dict[str, Any]:
    while typing.get_origin(type_) is typing.Annotated:
        type_ = typing.get_args(type_)[0]
    fields = getattr(type_, "__pydantic_fields__", None)
    if fields is not None:
        return {(f.alias or name): f.annotation for name, f in fields.items()}
    if typing_extensions.is_typeddict(type_):
        return typing_extensions.get_type_hints(type_)
    return {}


def line_of(path: Path, keys: tuple) -> int | None:
    """The 1-based line of the YAML file ``path`` where the value under ``keys`` is written: the
    line of the deepest of those keys that the file writes (through ``<<`` merges, to the line
    in the anchored mapping), None where the file cannot be read again."""
    try:
        node = yaml.compose(Path(path).read_text(), Loader=yaml.SafeLoader)
    except (OSError, yaml.YAMLError):
        return None
    line = None
    for key in keys:
        found = _child(node, key)
        if found is None:
            continue  # a key no file writes (a union's tag); the next may be there
        line, node = found
    return line


def _child(node: Any, key: Any) -> tuple[int, Any] | None:
    if isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
        item = node.value[key]
        return item.start_mark.line + 1, item
    if not isinstance(node, yaml.MappingNode):
        return None
    merged = []
    for k, v in node.value:
        if k.tag == "tag:yaml.org,2002:merge":
            merged.extend(v.value if isinstance(v, yaml.SequenceNode) else [v])
        elif k.value == str(key):
            return k.start_mark.line + 1, v
    for m in merged:
        if (found := _child(m, key)) is not None:
            return found
    return None
