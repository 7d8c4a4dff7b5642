"""Config as data: TOML files loaded into frozen dataclasses, unknown keys are errors.

``load_toml`` reads a file with clear errors; ``build_dataclass`` turns a mapping into a frozen
dataclass, checking keys and simple types (``int``, ``float``, ``str``, ``bool``, ``X | None``,
``tuple[X, ...]``, nested dataclasses). Units live in field names (``pulse_freq_hz``).

Devices and settings shipped with bimscan are TOML files too (``read_package_tables``), each kind
in one registry (a plain dict: ``SCANNERS``, ``LIDARS``, ``PLATFORMS``, ``PRESETS``); wherever a
user names one, a file of the same keys does as well, and ``load_named`` reads either.
"""

from __future__ import annotations

import dataclasses
import datetime
import tomllib
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from bimscan.errors import ConfigError, InputFileError
from bimscan.files import check_input_file

T = TypeVar("T")


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; missing files and syntax errors become one-line errors."""
    path = check_input_file(path, what="a TOML file")
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc}); fix the syntax") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file; pass a TOML file") from exc


def read_package_tables(package: str, name: str) -> dict[str, dict[str, Any]]:
    """The TOML shipped in ``package`` as tables by name: each file of the folder ``name`` (name: the
    file's stem), or, when ``name`` is a ``.toml`` file, each top-level table of it."""
    where = resources.files(package) / name
    if name.endswith(".toml"):
        return dict(tomllib.loads(where.read_text("utf-8")))
    return {p.name.removesuffix(".toml"): tomllib.loads(p.read_text("utf-8"))
            for p in sorted(where.iterdir(), key=lambda p: p.name) if p.name.endswith(".toml")}


def load_named(source: str | Path, registry: Mapping[str, T], *, kind: str,
               read: Callable[[dict[str, Any], Path], T], names: Iterable[str] | None = None,
               file: str | None = None) -> T:
    """A built-in entry of ``registry`` by its name, or what ``read`` makes of the TOML file ``source``
    (its table and its path): the one way a scanner, a lidar, a platform or a preset is given by
    "a name or a file". ConfigError when ``source`` is neither, listing the built-in ``names``
    (default: the registry's). ``kind`` names what is sought (``"scanner"``), ``file`` the file to
    pass instead (default: a ``kind`` TOML file)."""
    if isinstance(source, str) and source in registry:
        return registry[source]
    path = Path(source)
    if not path.is_file():
        listed = ", ".join(registry if names is None else names)
        raise ConfigError(f"{kind} {str(source)!r} is neither a file nor a known {kind} ({listed}); pass "
                          f"{file or f'a {kind} TOML file'}")
    return read(load_toml(path), path)


def build_dataclass(cls: type[T], data: Mapping[str, Any], *, where: str) -> T:
    """Build the frozen dataclass ``cls`` from ``data``.

    ``where`` names the place in the file (``"scanner.toml [scanner]"``) for error messages.
    Missing fields fall back to the dataclass defaults; fields without defaults are required.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__} {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed keys are "
            f"{', '.join(sorted(fields))}"
        )
    hints = typing.get_type_hints(cls)
    values: dict[str, Any] = {}
    for name, field in fields.items():
        if name in data:
            values[name] = _coerce(data[name], hints[name], where=f"{where} key {name!r}")
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    try:
        return cls(**values)
    except ConfigError as exc:  # a dataclass's own check does not know the file it was read from
        raise exc if str(exc).startswith(where) else type(exc)(f"{where}: {exc}") from exc
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _coerce(value: Any, hint: Any, *, where: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (types.UnionType, typing.Union):
        options = typing.get_args(hint)
        if value is None and type(None) in options:
            return None
        errors: list[ConfigError] = []
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(value, option, where=where)
            except ConfigError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]  # of its own kind (impossible scan settings stay a ScannerSettingsError)
        raise ConfigError(f"{where}: invalid value {value!r}")
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], where=where) for v in value)
        if len(args) != len(value):
            raise ConfigError(f"{where}: expected a list of {len(args)} values, got {value!r}")
        return tuple(_coerce(v, a, where=where) for v, a in zip(value, args, strict=True))
    if dataclasses.is_dataclass(hint):
        return build_dataclass(hint, value, where=where)  # type: ignore[arg-type]
    if hint is Any:
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if hint is str:
        if isinstance(value, datetime.date | datetime.time):  # a TOML date (at = 2024-05-01) where text is read
            return value.isoformat()
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if typing.get_origin(hint) is typing.Literal:
        allowed = typing.get_args(hint)
        if value not in allowed:
            raise ConfigError(f"{where}: expected one of {', '.join(map(repr, allowed))}, got {value!r}")
        return value
    if origin is dict or hint is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return dict(value)
    return value


def resolve_path(base: Path, value: str) -> Path:
    """``value`` as a path, relative to ``base`` unless absolute (``~`` expanded)."""
    candidate = Path(value).expanduser()
    return candidate if candidate.is_absolute() else base / candidate


def over_base(own: Mapping[str, Any], base: Mapping[str, Any], *,
              keys: tuple[str, ...] | None = None) -> dict[str, Any]:
    """A file over its ``base`` file (dataset specs and experiments alike): every key of ``base``
    (of ``keys`` only, when given) this file does not set is taken as it is; a table both set is
    merged key by key, one level deep (this file's keys replace the base's, the others stay);
    any other value this file sets replaces the base's. ``base``'s relative paths must already be
    made absolute by the caller (they are relative to the base file)."""
    merged = dict(own)
    for key, value in base.items():
        if keys is not None and key not in keys:
            continue
        if key not in own:
            merged[key] = value
        elif isinstance(value, Mapping) and isinstance(own[key], Mapping):
            merged[key] = {**value, **own[key]}
    return merged


def base_file(value: Any, path: Path, *, where: str, kind: str) -> Path:
    """The file that the ``base`` key (at ``where`` in ``path``) names, relative to ``path``'s folder
    (``~`` expanded), checked: text, not ``path`` itself, present. ``kind``: what the file must be
    (for the messages). Experiment files and dataset specs both start from a base this way."""
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{path} {where}: expected the path of another {kind}")
    resolved = resolve_path(path.resolve().parent, value).resolve()
    if resolved == path.resolve():
        raise ConfigError(f"{path} {where}: names this file itself; name another {kind}")
    if not resolved.is_file():
        raise InputFileError(f"{resolved}: {where} not found; fix the path in {path}")
    return resolved
