"""Settings with their constraints declared once, next to the field.

A settings class is a frozen dataclass deriving from ``Checked``; each field that has a range
declares it where it is declared, with its default::

    @dataclass(frozen=True)
    class TrainConfig(Checked):
        max_lr: float = setting(2e-3, within=Range(0, 1, low_open=True))
        epochs: int = setting(100, within=Range(1, 100_000))
        amp: Literal["float16", "bfloat16", "off"] = "float16"   # choices: the Literal itself

Construction checks every declared range and every ``Literal`` choice (``check_settings``), so
a value is refused the same way whether it came from a TOML file (``toml_files.build_dataclass``),
the CLI or Python, with one message shape: ``max_lr must be a number in (0, 1], got 1e+09``.
Checks across fields stay in the class's own ``check`` method, which runs after these.
(scikit-learn's ``_parameter_constraints`` is the model: constraints are data, one validator.)

A choice among a registry's names (a plain dict filled where it is defined, e.g. the IFC length
units) is ``setting(..., among=REGISTRY)``, so the names stay in the registry alone. ``hint``
says in the message what the number means where its name cannot (``sigma_m must be a number in
[0, 1] (metres per 10 m walked), got 5``).

``setting(..., effect=...)`` also says what a change of the value touches: ``"model"`` (the
default: what is computed), ``"scores"`` (how a trained model is evaluated, not the model), or
``"runtime"`` (where and how fast it runs, nothing computed). Resuming a training run accepts
changes of "scores" and "runtime" settings; an experiment's fingerprint ignores "runtime" ones.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any, Literal

from bimscan.errors import ConfigError

Effect = Literal["model", "scores", "runtime"]


@dataclass(frozen=True)
class Range:
    """Numbers from ``low`` to ``high`` (None: unbounded on that side), each end closed unless
    ``low_open``/``high_open``. Integers are told by the field's type, not here."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def admits(self, value: float) -> bool:
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return not (self.high is not None and (value >= self.high if self.high_open else value > self.high))

    def describe(self, *, integer: bool) -> str:
        """``in (0, 1]``, ``in 1..64``, ``>= 0``, ``at most 10`` (integers as ``a..b``)."""
        def show(v: float) -> str:
            return str(int(v)) if integer else f"{v:g}"

        low, high = self.low, self.high
        if low is not None and high is not None:
            if integer and not self.low_open and not self.high_open:
                return f"in {show(low)}..{show(high)}"
            return f"in {'(' if self.low_open else '['}{show(low)}, {show(high)}{')' if self.high_open else ']'}"
        if low is not None:
            return f"{'>' if self.low_open else '>='} {show(low)}"
        if high is not None:
            return f"{'<' if self.high_open else '<='} {show(high)}"
        return "finite"

    @property
    def bounded(self) -> bool:
        return self.low is not None or self.high is not None


def setting(default: Any = dataclasses.MISSING, *, factory: Any = dataclasses.MISSING, within: Range | None = None,
            each: Range | None = None, among: Collection[Any] | None = None, hint: str | None = None,
            effect: Effect = "model") -> Any:
    """A dataclass field with its constraint: ``within`` for a number, ``each`` for every number of a
    tuple (nested tuples too), ``among`` for a value that must be one of a registry's names (kept by
    reference: the registry as it is when checked); ``hint``: what the value means, for the message
    of a refusal (a unit, a reason); ``effect``: see the module docs."""
    metadata = {"within": within, "each": each, "among": among, "hint": hint, "effect": effect}
    if factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def effect_of(cls: type, name: str) -> Effect:
    """What a change of field ``name`` of settings class ``cls`` touches (see the module docs)."""
    for item in dataclasses.fields(cls):  # type: ignore[arg-type]
        if item.name == name:
            return item.metadata.get("effect", "model")
    raise KeyError(f"{cls.__name__} has no field {name!r}")


def choices_of(cls: type, name: str) -> tuple[Any, ...]:
    """The values field ``name`` of settings class ``cls`` takes (its ``Literal``, or the registry
    of its ``among``), for a CLI's choice list: the one declaration, never a copy."""
    choices = _literal_choices(_hints(cls).get(name))
    if choices is None:
        among = next((f.metadata.get("among") for f in dataclasses.fields(cls)  # type: ignore[arg-type]
                      if f.name == name), None)
        choices = None if among is None else tuple(among)
    if choices is None:
        raise KeyError(f"{cls.__name__}.{name} is not a choice")
    return choices


def default_of(cls: type, name: str) -> Any:
    """The default of field ``name`` of settings class ``cls`` (for a CLI's shown default)."""
    for item in dataclasses.fields(cls):  # type: ignore[arg-type]
        if item.name == name:
            if item.default is not dataclasses.MISSING:
                return item.default
            if item.default_factory is not dataclasses.MISSING:
                return item.default_factory()
            raise KeyError(f"{cls.__name__}.{name} has no default")
    raise KeyError(f"{cls.__name__} has no field {name!r}")


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_integer(hint: Any) -> bool:
    if hint is int:
        return True
    origin = typing.get_origin(hint)
    return origin is not None and any(_is_integer(a) for a in typing.get_args(hint) if a is not type(None))


def _numbers(value: Any) -> list[Any]:
    """Every number in a (nested) tuple, in order."""
    if isinstance(value, list | tuple):
        return [n for item in value for n in _numbers(item)]
    return [value]


def _literal_choices(hint: Any) -> tuple[Any, ...] | None:
    """The allowed values of a ``Literal`` hint, or of a tuple of them (None: not a choice)."""
    if typing.get_origin(hint) is Literal:
        return typing.get_args(hint)
    if typing.get_origin(hint) is tuple:
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return _literal_choices(args[0])
    return None


_SIMPLE = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _simple_type(hint: Any) -> type | None:
    """``bool``/``int``/``float``/``str`` for such a hint or its ``X | None``, else None."""
    if hint in _SIMPLE:
        return hint
    if typing.get_origin(hint) in (types.UnionType, typing.Union):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1 and args[0] in _SIMPLE:
            return args[0]
    return None


def _of_type(value: Any, kind: type) -> bool:
    if kind is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


def check_settings(settings: Any) -> None:
    """The first field of ``settings`` of the wrong simple type, outside its declared range or not
    among its choices, refused with the class's ``refusal`` (a ConfigError)."""
    cls = type(settings)
    hints = _hints(cls)
    refuse = getattr(settings, "refusal", ConfigError)
    for item in dataclasses.fields(settings):
        value = getattr(settings, item.name)
        if value is None:
            continue
        hint = hints.get(item.name)
        note = f" ({item.metadata['hint']})" if item.metadata.get("hint") else ""
        kind = _simple_type(hint)
        if kind is not None and not _of_type(value, kind):
            raise refuse(f"{item.name} must be {_SIMPLE[kind]}{note}, got {_show(value)}")
        choices = _literal_choices(hint)
        if choices is not None:
            values = value if isinstance(value, tuple) and typing.get_origin(hint) is tuple else (value,)
            wrong = [v for v in values if v not in choices]
            if wrong:
                raise refuse(f"{item.name} takes {', '.join(map(repr, choices))}{note}, got {wrong[0]!r}")
        among = item.metadata.get("among")
        if among is not None and not _is_among(value, among):
            raise refuse(f"{item.name} takes {', '.join(map(repr, among))}{note}, got {value!r}")
        within, each = item.metadata.get("within"), item.metadata.get("each")
        if within is not None:
            problem = range_problem(item.name, value, within, integer=_is_integer(hint), hint=item.metadata.get("hint"))
            if problem is not None:
                raise refuse(problem)
        if each is not None:
            for number in _numbers(value):
                if isinstance(number, bool) or not isinstance(number, int | float) or not each.admits(number):
                    allowed = f"numbers {each.describe(integer=False)}" if each.bounded else "finite numbers"
                    raise refuse(f"{item.name} takes {allowed}{note}, got {_show(number)} in {list(value)}")


def range_problem(name: str, value: Any, within: Range, *, integer: bool = False, hint: str | None = None) -> str | None:
    """What is wrong with ``value`` for the number ``name`` declared ``within`` (None: nothing), in the
    words construction uses (``voxel_size_m must be a number > 0 (metres), got 0``): for a number
    that a class outside the settings tables takes, checked against the same declared range."""
    if not isinstance(value, bool) and isinstance(value, int | float) and within.admits(value):
        return None
    kind_words = "an integer" if integer else "a number"
    allowed = (f"{kind_words} {within.describe(integer=integer)}" if within.bounded
               else f"a finite {kind_words.split()[-1]}")
    note = f" ({hint})" if hint else ""
    return f"{name} must be {allowed}{note}, got {_show(value)}"


def _is_among(value: Any, registry: Collection[Any]) -> bool:
    try:
        return value in registry
    except TypeError:  # unhashable: no registry name
        return False


def _show(value: Any) -> str:
    """A value for a message, numbers short (a 300-digit integer is not read, it is counted)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**15:
        return f"{float(value):.3g}"
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value)


class Checked:
    """Base of settings classes: construction checks the declared constraints
    (``check_settings``), then the class's own cross-field ``check``; both refuse with
    ``refusal`` (a ConfigError; a class may give its own kind or context, e.g. a scanner's name)."""

    def __post_init__(self) -> None:
        check_settings(self)
        self.check()

    def check(self) -> None:
        """Constraints across fields (none by default)."""

    def refusal(self, problem: str) -> ConfigError:
        """The error for one problem with these settings."""
        return ConfigError(problem)


__all__ = ["Checked", "Effect", "Range", "check_settings", "choices_of", "default_of", "effect_of", "range_problem",
           "setting"]
