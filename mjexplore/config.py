"""Frozen-dataclass configs from YAML: unknown keys, wrong types and bad values are refused
with a message that names the key and says what is expected."""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from mjexplore.errors import UserInputError

T = TypeVar("T")


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _convert(option, value, where)
            except UserInputError as exc:
                errors.append(str(exc))
        raise UserInputError(errors[0])
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise UserInputError(f"{where}: expected a list, got {value!r}.")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise UserInputError(f"{where}: expected {len(args)} values, got {len(value)}.")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserInputError(f"{where}: expected a number, got {value!r}.")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise UserInputError(f"{where}: expected a whole number, got {value!r}.")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise UserInputError(f"{where}: expected true or false, got {value!r}.")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise UserInputError(f"{where}: expected a string, got {value!r}.")
        return value
    return value


def from_dict(cls: type[T], data: Any, where: str = "config") -> T:
    """Builds the dataclass ``cls`` from a (YAML) mapping, recursively.

    Raises:
        UserInputError: unknown key, wrong type, or a value the dataclass rejects.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise UserInputError(f"{where}: expected a mapping of keys to values, got {data!r}.")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise UserInputError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; valid keys "
                             f"are {', '.join(fields)}.")
    kwargs = {k: _convert(hints[k], v, f"{where}.{k}") for k, v in data.items()}
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        raise UserInputError(f"{where}: {exc}") from None


def to_dict(config: Any) -> Any:
    """A dataclass config as plain YAML/JSON data (tuples become lists)."""
    if dataclasses.is_dataclass(config):
        return {f.name: to_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, (list, tuple)):
        return [to_dict(v) for v in config]
    return config


def load_yaml_config(cls: type[T], path: str | Path) -> T:
    """Reads a YAML file into the dataclass ``cls``.

    Raises:
        UserInputError: missing or unreadable file, YAML syntax error, or bad content.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserInputError(f"cannot read config {str(path)!r}: {exc.strerror}; give the path "
                             "of a YAML file such as training/gvn.yaml.") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise UserInputError(f"config {str(path)!r} is not valid YAML: {exc}") from None
    return from_dict(cls, data, path.name)
