"""One exception hierarchy for everything a user can get wrong.

Every message says what was wrong (with the offending value) and what to do about it, in one
line: the CLI prints ``error: <message>`` and exits non-zero, never a traceback. Numbers from the
user's files go into messages through ``number``, so that a line stays a line whatever they hold.
"""

from __future__ import annotations

import math


def number(value: float, decimals: int = 2) -> str:
    """``value`` for a message: at most ``decimals`` decimals, trailing zeros dropped, and in
    scientific notation from 1e9 on (a coordinate of 1e300 reads ``1e+300``, not 301 digits)."""
    value = float(value)
    if not math.isfinite(value) or abs(value) >= 1e9:
        return f"{value:.6g}"
    text = f"{value:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


class BimscanError(Exception):
    """Base of all user-facing errors."""

    exit_code: int = 1


class InputFileError(BimscanError):
    """A file given by the user is missing, unreadable or of the wrong kind."""


class IfcError(BimscanError):
    """An IFC file could not be parsed or holds nothing scannable."""


class EmptyModelError(IfcError):
    """An IFC model parsed, but no element produced geometry."""


class ConfigError(BimscanError):
    """A configuration file or value (TOML, scheme, spec) is invalid."""


class SchemeError(ConfigError):
    """A label scheme is invalid."""


class ScannerSettingsError(ConfigError):
    """Scanner settings are impossible, or outside the device's limits under --strict."""


class StationError(BimscanError):
    """A scan station is unusable: inside a solid, outside the building, or none could be planned."""


class OutputError(BimscanError):
    """An output could not be written (bad path, existing file, full disk)."""


class SemanticError(BimscanError):
    """A cloud whose labels contradict its component table, or an output that does not hold what
    was written to it (a bug or a corrupted file: the post-checks failed)."""


class DatasetError(BimscanError):
    """A dataset build or dataset folder is inconsistent."""


class CompareError(BimscanError):
    """A scan could not be aligned to its model, or compared with it (no overlap, wrong units)."""


class LearnError(BimscanError):
    """A training, evaluation or prediction input is invalid."""
