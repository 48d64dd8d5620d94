"""Frozen-dataclass configs from YAML: unknown keys, wrong types and bad values are refused
with a message that names the key and says what is expected.

A YAML config may start from another: ``extends: gvn_anchor.yaml`` (a path relative to the
file's folder) reads that file first, then lays this file's keys over it. Mappings merge key
by key, at every depth; any other value (a list, a number, ``null``) replaces the base's. A
recipe then states only what it changes, and the run's saved ``config.yaml`` holds the
merged result.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar

import yaml

from mjexplore.errors import UserInputError


class _Dataclass(Protocol):
    """A dataclass (what :func:`dataclasses.fields` takes)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]


T = TypeVar("T", bound=_Dataclass)


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
        # ``tp`` is a type hint here, so the dataclass it names is a class, not an instance.
        return from_dict(typing.cast(type[_Dataclass], tp), value, where)
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
        try:
            number = float(value)
        except OverflowError:  # A whole number too large for a float.
            number = math.inf
        if not math.isfinite(number):
            raise UserInputError(f"{where}: expected a finite number, got {value!r}.")
        return number
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
    unknown = sorted(map(str, set(data) - set(fields)))  # YAML keys may be numbers too.
    if unknown:
        raise UserInputError(f"{where}: unknown key(s) {', '.join(unknown)}; valid keys "
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


EXTENDS = "extends"


def merge_mappings(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """``override`` laid over ``base``: mappings merge key by key, recursively; any other
    value of ``override`` replaces the base's. Neither argument is modified."""
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = merge_mappings(merged[key], value)
        else:
            merged[key] = value
    return merged


def _read_layers(path: Path, chain: tuple[Path, ...] = ()) -> list[tuple[str, dict[str, Any]]]:
    """(file name, its own mapping) of ``path`` and of every file it ``extends``, the file
    itself first (module docstring).

    Raises:
        UserInputError: missing or unreadable file, YAML syntax error, content that is not a
            mapping, or an ``extends`` that is not a file name or leads back to itself.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise UserInputError(f"cannot read config {str(path)!r}: {exc.strerror}; give the path "
                             "of a YAML file such as training/gvn.yaml.") from None
    except UnicodeDecodeError as exc:
        raise UserInputError(f"config {str(path)!r} is not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start}): give a YAML file, saved as UTF-8.") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise UserInputError(f"config {str(path)!r} is not valid YAML: {exc}") from None
    if data is None:
        raise UserInputError(f"config {str(path)!r} is empty: give the settings (see "
                             "training/gvn_v3.yaml), or 'extends: FILE' to start from another.")
    if not isinstance(data, dict):
        raise UserInputError(f"{path.name}: expected a mapping of keys to values, got {data!r}.")
    if EXTENDS not in data:
        return [(path.name, data)]
    base_name = data.pop(EXTENDS)
    if not isinstance(base_name, str) or not base_name or "\0" in base_name:
        raise UserInputError(f"{path.name}: {EXTENDS} must name the YAML file this one starts "
                             f"from (relative to {str(path.parent)!r}), got {base_name!r}.")
    chain = (*chain, path.resolve())
    base_path = path.parent / base_name
    if base_path.resolve() in chain:
        names = " -> ".join(p.name for p in (*chain, base_path))
        raise UserInputError(f"{path.name}: {EXTENDS} leads back to a file already read "
                             f"({names}); break the loop.")
    return [(path.name, data), *_read_layers(base_path, chain)]


def _merge_layers(layers: list[tuple[str, dict[str, Any]]]) -> dict[str, Any]:
    merged: dict[str, Any] = {}
    for _, data in reversed(layers):
        merged = merge_mappings(merged, data)
    return merged


def _where_set(message: str, name: str, layers: list[tuple[str, dict[str, Any]]]) -> str:
    """The files of an ``extends`` chain that set the key a :func:`from_dict` error
    ``message`` (about the merged config named ``name``) is about, child first."""
    where = message[len(name):].split(": ", 1)[0] if message.startswith(name) else ""
    keys = [k for k in re.split(r"\.|\[\d+\]", where) if k]
    unknown = re.search(r"unknown key\(s\) (.*?); valid keys", message)
    leaves = [[*keys, k] for k in unknown.group(1).split(", ")] if unknown else [keys]

    def sets(data: Any, path: list[str]) -> bool:
        for key in path:
            if not isinstance(data, dict) or key not in data:
                return False
            data = data[key]
        return True

    return ", ".join(n for n, data in layers if any(sets(data, leaf) for leaf in leaves))


def load_yaml_config(cls: type[T], path: str | Path) -> T:
    """Reads a YAML file (and the files it ``extends``) into the dataclass ``cls``.

    Raises:
        UserInputError: missing or unreadable file, YAML syntax error, or bad content.
    """
    layers = _read_layers(Path(path))
    name = Path(path).name
    try:
        return from_dict(cls, _merge_layers(layers), name)
    except UserInputError as exc:
        if len(layers) == 1:
            raise
        files = _where_set(str(exc), name, layers) or "none of them alone"
        chain = " -> ".join(n for n, _ in layers)
        raise UserInputError(f"{exc} (the config merges {chain}; set in: {files})") from None
