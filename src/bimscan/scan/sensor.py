"""Sensor realism beyond the paper: which effects a scan simulates, and their settings, as data.

``SensorModel`` is one frozen value held by ``ScanRecipe.sensor``. ``realism`` picks the defaults
of every effect: ``"paper"`` (the default) is the SPC paper's scanner, a thin ray with Gaussian
range and angle noise, bit for bit what bimscan did before these effects existed; ``"full"`` turns
every effect on with the defaults below. Each effect can also be switched on or off alone (a
``None`` switch follows ``realism``). The models, their formulas and sources are in
docs/guide/scanner.md ("Sensor realism beyond the paper"); in short:

- ``footprint``: the beam has the scanner's divergence; pulses whose footprint may straddle a
  depth or component edge (their neighbours in the scan grid disagree) are sampled with
  HELIOS++'s sub-ray pattern (``beam_sample_quality`` rings); sub-ray echoes closer in range
  than the pulse's range resolution merge into one return (mixed pixels), the rest are separate
  returns (``returns``: first, last, strongest or all).
- ``detection``: a return is detected with the probability the lidar range equation and speckle
  give for its energy (reflectance, incidence, share of the footprint) and range, calibrated to
  the scanner's datasheet reach.
- ``geometric_noise``: the range noise grows with range and with 1 / cos(incidence).
- ``materials``: near-infrared reflectance from IFC material and style names (a small table).
- ``glass``: transparent surfaces pass the beam; each crossing echoes with a small probability.
- ``color``: per-point RGB from the surface style colour with simple shading noise.
- ``deviations``: as-built deviations of every component (rigid offset and tilt within
  construction tolerances, optional waviness).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError

Realism = Literal["paper", "full"]
ReturnMode = Literal["first", "last", "strongest", "all"]
REALISMS: tuple[str, ...] = typing.get_args(Realism)
RETURN_MODES: tuple[str, ...] = typing.get_args(ReturnMode)
# The switches; None follows ``realism`` (off for paper, on for full).
EFFECTS = ("footprint", "detection", "geometric_noise", "materials", "glass", "color", "deviations")
# What a moving multi-beam lidar's pulses get (a mobile scan): the effects decided by each pulse's
# own hit. The others stay with tripods: the footprint's edge test reads the tripod's scan-line
# grid, and glass (echoes merged by the pulse length) and detection (calibrated by the datasheet's
# reach) need facts the shipped lidar files do not give.
MOBILE_EFFECTS = ("geometric_noise", "materials", "color", "deviations")
# The effects each setting acts through: a setting away from its default while none of its effects
# is on changes no byte, so a scan refuses it (``SensorModel.idle_settings``). max_incidence_deg
# caps 1 / cos(incidence) for the geometric noise and for the waviness of as-built surfaces.
SETTING_EFFECTS: dict[str, tuple[str, ...]] = {
    "beam_sample_quality": ("footprint",), "adaptive_footprint": ("footprint",), "edge_depth_m": ("footprint",),
    "returns": ("footprint", "glass"), "max_returns": ("footprint", "glass"),  # one echo per pulse without them
    "speckle_cells": ("detection",),
    "range_noise_ppm": ("geometric_noise",), "max_incidence_deg": ("geometric_noise", "deviations"),
    "material_table": ("materials", "glass", "color"),
    "glass_return_probability": ("glass",), "max_glass_layers": ("glass",),
    "color_noise": ("color",), "ambient": ("color",),
    "position_tolerance_m": ("deviations",), "level_tolerance_m": ("deviations",),
    "plumb_tolerance_m": ("deviations",), "sigmas_per_tolerance": ("deviations",), "waviness_m": ("deviations",),
    "waviness_wavelength_m": ("deviations",),
}
# The ``bimscan scan`` flag of each effect that has one (the others: --realism full or --sensor FILE).
EFFECT_FLAGS = {"footprint": "--footprint", "detection": "--detection", "glass": "--glass", "color": "--rgb",
                "deviations": "--as-built"}
MAX_BEAM_SAMPLE_QUALITY = 6  # 1 + 3 Q (Q - 1) sub-rays: 91 at 6
MAX_RETURNS = 15  # what LAS point formats 6-10 can number


@dataclass(frozen=True)
class SensorModel(Checked):
    """What the virtual scanner simulates beyond a thin ray with Gaussian noise (see the module docs).

    Switches (``None``: follow ``realism``): footprint, detection, geometric_noise, materials,
    glass, color, deviations.

    Footprint: beam_sample_quality Q (HELIOS++'s ``beamSampleQuality``: a centre ray and Q - 1
    rings of 6, 12, ... sub-rays); adaptive_footprint (sub-rays only where neighbouring pulses
    disagree; False: on every pulse, as HELIOS++ does); edge_depth_m (a pulse's range differing
    from the straight-line prediction of its neighbours by more than this marks a depth edge);
    returns (which echoes become points: first, last, strongest, all) and max_returns (at most this
    many points per pulse under "all").
    Detection: speckle_cells M (speckle cells the receiver averages; 1 = fully developed speckle).
    Geometric noise: range_noise_ppm (growth of the range sigma with range, mm per km) and
    max_incidence_deg (the 1 / cos(incidence) growth stops here).
    Materials: material_table (a TOML file replacing the built-in table; None: built-in).
    Glass: glass_return_probability (chance that a transparent surface crossing echoes) and
    max_glass_layers (transparent surfaces one ray crosses at most).
    Colour: color_noise (relative sigma of each point's brightness) and ambient (share of light
    that does not depend on the incidence angle).
    Deviations: position_tolerance_m, level_tolerance_m, plumb_tolerance_m (ACI 117 limits),
    sigmas_per_tolerance (a tolerance is this many sigmas), waviness_m (amplitude of surface
    waviness, 0 = none) and waviness_wavelength_m.
    """

    realism: Realism = "paper"
    footprint: bool | None = None
    beam_sample_quality: int = setting(3, within=Range(1, MAX_BEAM_SAMPLE_QUALITY))
    adaptive_footprint: bool = True
    edge_depth_m: float = setting(0.02, within=Range(1e-6, 10.0))
    returns: ReturnMode = "first"
    max_returns: int = setting(4, within=Range(1, MAX_RETURNS))
    detection: bool | None = None
    speckle_cells: int = setting(1, within=Range(1, 64))
    geometric_noise: bool | None = None
    range_noise_ppm: float = setting(10.0, within=Range(0.0, 1e5))
    max_incidence_deg: float = setting(85.0, within=Range(0.0, 89.9))
    materials: bool | None = None
    material_table: str | None = None
    glass: bool | None = None
    glass_return_probability: float = setting(0.1, within=Range(0.0, 1.0))
    max_glass_layers: int = setting(6, within=Range(1, 32))
    color: bool | None = None
    color_noise: float = setting(0.03, within=Range(0.0, 1.0))
    ambient: float = setting(0.5, within=Range(0.0, 1.0))
    deviations: bool | None = None
    position_tolerance_m: float = setting(0.025, within=Range(0.0, 1.0))
    level_tolerance_m: float = setting(0.019, within=Range(0.0, 1.0))
    plumb_tolerance_m: float = setting(0.025, within=Range(0.0, 1.0))
    sigmas_per_tolerance: float = setting(2.0, within=Range(0.5, 10.0))
    waviness_m: float = setting(0.0, within=Range(0.0, 0.5))
    waviness_wavelength_m: float = setting(2.0, within=Range(0.01, 1000.0))

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"impossible sensor settings: {problem}")

    def on(self, effect: str) -> bool:
        """Whether ``effect`` (one of ``EFFECTS``) is simulated."""
        value = getattr(self, effect)
        return self.realism == "full" if value is None else bool(value)

    def resolved(self) -> SensorModel:
        """This model with every switch decided (True/False), as recorded in metadata."""
        return dataclasses.replace(self, **{effect: self.on(effect) for effect in EFFECTS})

    def for_mobile(self) -> SensorModel:
        """This model for a mobile scan: effects outside ``MOBILE_EFFECTS`` off (``realism = "full"``
        turns on the rest); one of them switched on by name is refused in one line."""
        asked = [name for name in EFFECTS if name not in MOBILE_EFFECTS and getattr(self, name)]
        if asked:
            raise ConfigError(f"{', '.join(asked)}: simulated for tripod scans only; switch "
                              f"{'it' if len(asked) == 1 else 'them'} off for a mobile platform (mobile scans "
                              f"simulate {', '.join(MOBILE_EFFECTS)})")
        return dataclasses.replace(self, **{name: False for name in EFFECTS if name not in MOBILE_EFFECTS})

    def idle_settings(self) -> dict[str, tuple[str, ...]]:
        """The settings away from their defaults that change nothing here, each with the effects it
        acts through (``SETTING_EFFECTS``): none of them is on (``max_returns`` also needs
        ``returns = "all"``, ``waviness_wavelength_m`` a ``waviness_m`` above 0)."""
        defaults = SensorModel()
        idle = {}
        for name, effects in SETTING_EFFECTS.items():
            if getattr(self, name) == getattr(defaults, name):
                continue
            acts = any(self.on(effect) for effect in effects)
            if name == "max_returns":
                acts = acts and self.returns == "all"
            elif name == "waviness_wavelength_m":
                acts = acts and self.waviness_m > 0
            if not acts:
                idle[name] = effects
        return idle

    def check_settings_act(self, *, mobile: bool = False) -> None:
        """Raise ConfigError, in one line, when a setting would change nothing (``idle_settings``):
        an option either acts or is refused. ``mobile``: this is a mobile scan's model
        (``for_mobile``), whose pulses have no footprint, glass or detection."""
        idle = self.idle_settings()
        if not idle:
            return
        clauses = []
        for name, effects in idle.items():
            needs = " or ".join(effects)
            if name == "max_returns":
                needs = f"returns = 'all' and {needs}"
            elif name == "waviness_wavelength_m":
                needs = f"{needs} and waviness_m > 0"
            value = getattr(self, name)
            shown = repr(Path(value).name) if name == "material_table" else repr(value)
            clauses.append(f"{name} = {shown} (acts only with {needs})")
        names = ", ".join(idle)
        needed = [e for e in EFFECTS if any(e in effects for effects in idle.values())
                  and (not mobile or e in MOBILE_EFFECTS)]
        if not needed:  # only effects a mobile scan does not simulate
            advice = (f"a mobile scan simulates {', '.join(MOBILE_EFFECTS)} only, so leave {names} out")
        else:
            flags = [EFFECT_FLAGS[e] for e in needed if e in EFFECT_FLAGS] + ["--realism full"]
            advice = (f"switch {' or '.join(needed)} on ({', '.join(flags)}; in a dataset spec, its key or "
                      f"realism = 'full') or leave {names} out")
        raise ConfigError(f"sensor setting{'s' if len(idle) > 1 else ''} that would change nothing, the effect off: "
                          f"{'; '.join(clauses)}; {advice}")

    @property
    def is_paper(self) -> bool:
        """True when no effect is on: the scan is the paper's, bit for bit."""
        return not any(self.on(effect) for effect in EFFECTS)

    @property
    def needs_surfaces(self) -> bool:
        """Whether per-component reflectance, transparency or colour is used."""
        return self.on("materials") or self.on("glass") or self.on("color")

    def to_json(self) -> dict[str, Any]:
        """The resolved settings as JSON-able data."""
        return dataclasses.asdict(self.resolved())

    @staticmethod
    def preset(realism: str, **overrides: Any) -> SensorModel:
        """``realism``'s defaults with some settings replaced (None values ignored)."""
        return SensorModel(realism=realism, **{k: v for k, v in overrides.items() if v is not None})


def merge_sensor_tables(*tables: dict[str, Any] | None) -> dict[str, Any]:
    """Sensor settings tables merged key by key, later ones winning (a dataset config over its spec)."""
    merged: dict[str, Any] = {}
    for table in tables:
        if table:
            merged.update(table)
    return merged
