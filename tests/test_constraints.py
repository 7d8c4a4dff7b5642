"""The one validator of settings: ranges, choices, registry names and hints declared by the field."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import pytest

from bimscan.constraints import Checked, Range, choices_of, default_of, setting
from bimscan.errors import ConfigError

UNITS = {"m": 1.0, "mm": 0.001}


@dataclass(frozen=True)
class Walk(Checked):
    sigma_m: float = setting(0.0, within=Range(0.0, 1.0), hint="metres per 10 m walked")
    offset_m: float = setting(0.0, within=Range())
    unit: str | None = setting(None, among=UNITS)
    shares: tuple[float, ...] = setting((0.5,), each=Range(0.0, 1.0, low_open=True), hint="fractions")
    mode: Literal["walk", "run"] = "walk"


def test_a_value_out_of_range_is_refused_in_one_line_with_its_range_and_hint():
    with pytest.raises(ConfigError) as caught:
        Walk(sigma_m=5.0)
    assert str(caught.value) == "sigma_m must be a number in [0, 1] (metres per 10 m walked), got 5"


def test_a_number_that_must_only_be_finite_says_so():
    with pytest.raises(ConfigError, match="^offset_m must be a finite number, got inf$"):
        Walk(offset_m=math.inf)
    assert Walk(offset_m=-1e6).offset_m == -1e6


def test_a_name_outside_its_registry_is_refused_naming_the_registrys_names():
    with pytest.raises(ConfigError, match="^unit takes 'm', 'mm', got 'furlong'$"):
        Walk(unit="furlong")
    assert Walk(unit="mm").unit == "mm"


def test_each_number_of_a_tuple_is_checked_with_the_hint():
    with pytest.raises(ConfigError, match=r"^shares takes numbers in \(0, 1\] \(fractions\), got 0 in \[0.5, 0.0\]$"):
        Walk(shares=(0.5, 0.0))


def test_a_cli_reads_choices_from_the_literal_or_the_registry_and_defaults_from_the_field():
    assert choices_of(Walk, "mode") == ("walk", "run")
    assert choices_of(Walk, "unit") == ("m", "mm")
    assert default_of(Walk, "sigma_m") == 0.0
    with pytest.raises(KeyError):
        choices_of(Walk, "sigma_m")
