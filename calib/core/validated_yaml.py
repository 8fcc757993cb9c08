"""Validated YAML: load a file into a pydantic model, with errors a person can act on.

Shared by the rig's configuration (:mod:`rig.config`) and ``calib estimate --inputs``
(:mod:`calib.pipeline.inputs_file`); it imports pydantic and PyYAML, so the command lines import it
only when a file is read.

The safe loader only (no Python object tags), with duplicate mapping keys refused rather than
silently keeping the last. Validation problems are reported all at once as :class:`ConfigIssue` s
naming the line, the field path with list indices (``lamps[1].warmup.interval_s``, discriminator
tags dropped), the value found and what is allowed, with the closest valid key or choice suggested
for a typo.
"""

from __future__ import annotations

import difflib
import re
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from calib.core.errors import InputError

ModelT = TypeVar("ModelT", bound=BaseModel)


@dataclass(frozen=True)
class ConfigIssue:
    """One problem in a configuration file."""

    field: str
    message: str
    line: int | None = None

    def render(self, source: str) -> str:
        where = f"{source}:{self.line}" if self.line is not None else source
        return (
            f"{where}: {self.field}: {self.message}" if self.field else f"{where}: {self.message}"
        )


class ConfigError(InputError):
    """The configuration file is missing, unreadable, not valid YAML or not a valid rig configuration.

    ``str(error)`` has one line per issue: ``file:line: field.path: what is wrong and what is allowed``.
    """

    def __init__(self, source: str, issues: Sequence[ConfigIssue]) -> None:
        self.issues = tuple(issues)
        self.config_source = source
        super().__init__("\n".join(issue.render(source) for issue in self.issues))


class _UniqueKeyLoader(yaml.SafeLoader):
    """The safe loader, refusing duplicate mapping keys (YAML allows them, silently keeping the last)."""


def _construct_mapping_without_duplicates(
    loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False
) -> dict[Any, Any]:
    seen: dict[object, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if isinstance(key, typing.Hashable) and key in seen:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"duplicate key {key!r} (first on line {seen[key]})",
                key_node.start_mark,
            )
        if isinstance(key, typing.Hashable):
            seen[key] = key_node.start_mark.line + 1
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
    _construct_mapping_without_duplicates,
)


def _unwrap(annotation: object) -> object:
    """Strip ``Annotated`` and ``None`` from an annotation."""
    while typing.get_origin(annotation) is Annotated:
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(members) == 1:
            return _unwrap(members[0])
    return annotation


def _union_models(annotation: object) -> list[type[BaseModel]]:
    """The model members of a (discriminated) union annotation, else ``[]``."""
    if typing.get_origin(annotation) not in (typing.Union, types.UnionType):
        return []
    members = [_unwrap(a) for a in typing.get_args(annotation)]
    return [m for m in members if isinstance(m, type) and issubclass(m, BaseModel)]


def _kind_values(model: type[BaseModel]) -> tuple[str, ...]:
    field = model.model_fields.get("kind")
    return typing.get_args(field.annotation) if field is not None else ()


@dataclass
class _Location:
    """Where a pydantic error location points: its display path, data path and enclosing model."""

    display: str
    data_path: tuple[str | int, ...]
    model: type[BaseModel] | None
    annotation: object


def _locate(root_model: type[BaseModel], loc: tuple[str | int, ...]) -> _Location:
    """Walk ``root_model`` along a pydantic ``loc``, dropping discriminator tags from the path."""
    annotation: object = root_model
    model: type[BaseModel] | None = root_model
    display = ""
    data_path: list[str | int] = []
    for item in loc:
        annotation = _unwrap(annotation)
        union_members = _union_models(annotation)
        if union_members and isinstance(item, str):
            chosen = [m for m in union_members if item in _kind_values(m)]
            if chosen:
                annotation = chosen[0]
                model = chosen[0]
                continue
        if isinstance(item, int):
            display += f"[{item}]"
            data_path.append(item)
            args = typing.get_args(annotation)
            annotation = args[0] if args else object
            continue
        data_path.append(item)
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            model = annotation
            display += f".{item}" if display else str(item)
            field = annotation.model_fields.get(item)
            annotation = field.annotation if field is not None else object
        elif typing.get_origin(annotation) is dict:
            display += f"[{item!r}]"
            annotation = typing.get_args(annotation)[1]
        else:
            display += f".{item}" if display else str(item)
            annotation = object
    unwrapped = _unwrap(annotation)
    if isinstance(unwrapped, type) and issubclass(unwrapped, BaseModel):
        model = unwrapped
    return _Location(display, tuple(data_path), model, annotation)


def _did_you_mean(word: object, choices: Sequence[str]) -> str:
    if not isinstance(word, str):
        return ""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    if not close:
        close = difflib.get_close_matches(word.lower(), [c.lower() for c in choices], n=1)
        close = [c for c in choices if c.lower() in close]
    return f" (did you mean {close[0]!r}?)" if close else ""


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


_BOUND_WORDS = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤"}


def _field_bounds(
    model: type[BaseModel] | None, data_path: Sequence[str | int]
) -> dict[str, float]:
    """All numeric bounds declared on the field at the end of ``data_path`` (``{"gt": 0, "le": 6}``)."""
    if model is None or not data_path or not isinstance(data_path[-1], str):
        return {}
    field = model.model_fields.get(data_path[-1])
    if field is None:
        return {}
    bounds: dict[str, float] = {}
    for constraint in field.metadata:
        for name in _BOUND_WORDS:
            bound = getattr(constraint, name, None)
            if isinstance(bound, int | float):
                bounds[name] = float(bound)
    return bounds


def _message(error: Mapping[str, Any], location: _Location, parent: _Location) -> str:
    """One readable sentence for one pydantic error."""
    kind = error["type"]
    value = error.get("input")
    ctx = error.get("ctx") or {}
    if kind == "extra_forbidden":
        name = location.data_path[-1] if location.data_path else value
        allowed = sorted(parent.model.model_fields) if parent.model is not None else []
        return (
            f"unknown key {name!r}{_did_you_mean(name, allowed)}; "
            f"allowed keys here: {', '.join(allowed)}"
        )
    if kind == "missing":
        return "required key is missing"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        tags = [t.strip().strip("'") for t in str(ctx.get("expected_tags", "")).split(",")]
        if kind == "union_tag_not_found":
            return f"missing 'kind'; allowed kinds: {', '.join(tags)}"
        tag = ctx.get("tag")
        return (
            f"kind {tag!r} is not known{_did_you_mean(tag, tags)}; allowed kinds: {', '.join(tags)}"
        )
    if kind == "literal_error":
        expected = str(ctx.get("expected", ""))
        choices = [c.strip().strip("'") for c in re.split(r",| or ", expected) if c.strip()]
        return f"{_show(value)} is not allowed{_did_you_mean(value, choices)}; allowed: {expected}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        bounds = _field_bounds(parent.model, location.data_path) or {
            k: float(v) for k, v in ctx.items() if k in _BOUND_WORDS
        }
        shown = " and ".join(f"{_BOUND_WORDS[k]} {v:g}" for k, v in bounds.items())
        return f"{_show(value)} is out of range; must be {shown}"
    if kind in ("too_short", "too_long"):
        return f"{error['msg']} (got {_show(value)})"
    if kind == "string_pattern_mismatch":
        return (
            f"{_show(value)} is not allowed; use 1–64 letters, digits or '._+-', "
            "starting with a letter or digit"
        )
    if kind == "value_error":
        return str(error["msg"]).removeprefix("Value error, ")
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return f"expected a mapping of keys, got {_show(value)}"
    if kind == "list_type":
        return f"expected a list, got {_show(value)}"
    return f"{_show(value)} is not allowed: {error['msg']}"


def _line_of(root: yaml.Node | None, data_path: Sequence[str | int], *, key: bool) -> int | None:
    """1-based line of the YAML node at ``data_path`` (its key when ``key``), else its nearest parent."""
    node = root
    line = root.start_mark.line + 1 if root is not None else None
    for depth, item in enumerate(data_path):
        if isinstance(node, yaml.MappingNode):
            match = [(k, v) for k, v in node.value if getattr(k, "value", None) == str(item)]
            if not match:
                return line
            key_node, node = match[0]
            last = depth == len(data_path) - 1
            line = (key_node if key and last else node).start_mark.line + 1
        elif isinstance(node, yaml.SequenceNode) and isinstance(item, int):
            if not 0 <= item < len(node.value):
                return line
            node = node.value[item]
            line = node.start_mark.line + 1
        else:
            return line
    return line


def issues_from_validation(
    error: ValidationError, root_model: type[BaseModel], root: yaml.Node | None = None
) -> list[ConfigIssue]:
    """Readable :class:`ConfigIssue` s for a pydantic error on ``root_model`` data.

    ``root`` is the composed YAML node tree of the data, for line numbers.
    """
    issues = []
    for item in error.errors():
        loc = tuple(item["loc"])
        location = _locate(root_model, loc)
        parent = _locate(root_model, loc[:-1]) if loc else location
        field = location.display
        if item["type"] == "extra_forbidden":
            line = _line_of(root, location.data_path, key=True)
        elif item["type"] == "missing":
            line = _line_of(root, location.data_path[:-1], key=False)
        else:
            line = _line_of(root, location.data_path, key=False)
        issues.append(ConfigIssue(field or "(top level)", _message(item, location, parent), line))
    return issues


def parse_yaml_model(text: str, model: type[ModelT], source: str) -> ModelT:
    """Parse YAML ``text`` and validate it as ``model``.

    Raises
    ------
    ConfigError
        For YAML syntax errors (with line and column), duplicate keys, a top level that is not a
        mapping, or any validation problem (all reported at once, each with its line).
    """
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        column = f", column {mark.column + 1}" if mark is not None else ""
        problem = exc.problem or exc.context or "not valid YAML"
        raise ConfigError(
            source, [ConfigIssue("", f"invalid YAML{column}: {problem}", line)]
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(source, [ConfigIssue("", f"invalid YAML: {exc}")]) from None
    if data is None:
        raise ConfigError(source, [ConfigIssue("", "the file is empty")])
    if not isinstance(data, dict):
        raise ConfigError(
            source,
            [ConfigIssue("", f"expected a mapping of keys at the top level, got {_show(data)}", 1)],
        )
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(source, issues_from_validation(exc, model, root)) from None
