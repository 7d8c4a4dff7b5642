"""The site model: what the building looks like when it is scanned (one typed value).

``SiteModel`` is the ``site`` field of ``ScanRecipe``: the construction stage (which IFC classes
are built, optional partial states, a date in the model's work schedule) and the clutter and
temporary works standing on the floors. Its default (``finished``, no clutter) leaves a scene as
the model has it. It travels with the recipe from the CLI or the dataset spec to
``dress_scene`` and into every cloud's metadata (``to_json``).

In TOML (a dataset spec's ``[[configs]]`` or top level) the two fields read::

    stage = "structure"                                   # or a table:
    stage = { name = "structure", walls_missing_fraction = 0.3, props_fraction = 0.5 }
    clutter = { density = 0.15, kinds = ["office", "people"] }
"""

from __future__ import annotations

import dataclasses
import datetime
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError

# Stage name -> the IFC classes built by then (an element is kept when its class, or the class of
# the aggregate it is part of, descends from one of them); None: everything.
STRUCTURE_CLASSES = (
    "IfcSlab", "IfcWall", "IfcColumn", "IfcBeam", "IfcStair", "IfcStairFlight", "IfcRamp", "IfcRampFlight",
    "IfcRoof", "IfcMember", "IfcFooting", "IfcPile",
)
ENCLOSURE_CLASSES = ("IfcWindow", "IfcDoor", "IfcCurtainWall", "IfcPlate", "IfcRailing", "IfcShadingDevice")
STAGES: dict[str, tuple[str, ...] | None] = {
    "structure": STRUCTURE_CLASSES,
    "enclosed": STRUCTURE_CLASSES + ENCLOSURE_CLASSES,
    "finished": None,
}
DEFAULT_STAGE = "finished"
MAX_DENSITY_PER_M2 = 2.0  # beyond this a floor is a warehouse, not a room being scanned


@dataclass(frozen=True)
class StageSettings(Checked):
    """The construction stage of the scene.

    name: ``structure`` (slabs, walls, columns, beams, stairs), ``enclosed`` (+ windows, doors,
    curtain walls, railings), ``finished`` (everything). include: IFC classes built (replaces the
    stage's list when given); exclude: IFC classes taken out (both: ``IfcProduct`` classes of IFC2X3,
    IFC4 or IFC4X3, any case, kept in the schemas' spelling; an unknown name is refused). walls_missing_fraction: walls not
    yet built (each wall by its GlobalId and the seed, so a larger fraction removes a superset).
    ceilings_open_fraction: bays of the ceilings (between grid lines) without panels.
    props_fraction: rooms whose slab is propped (steel props on a grid under the soffit).
    at: an ISO date; elements whose construction task finishes later, or whose demolition task
    finished earlier, are not there (needs a work schedule in the model).
    """

    name: str = setting(DEFAULT_STAGE, among=STAGES)
    include: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    walls_missing_fraction: float = setting(0.0, within=Range(0.0, 1.0))
    ceilings_open_fraction: float = setting(0.0, within=Range(0.0, 1.0))
    props_fraction: float = setting(0.0, within=Range(0.0, 1.0))
    at: str | None = None

    def __post_init__(self) -> None:
        if self.at is not None:  # a date in any form it is read in becomes its ISO text (or is refused)
            object.__setattr__(self, "at", iso_date(self.at))
        for what in ("include", "exclude"):  # class names in the schemas' spelling (or refused)
            object.__setattr__(self, what, ifc_product_classes(getattr(self, what), what=f"stage {what}"))
        super().__post_init__()

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"stage {problem}")

    def check(self) -> None:
        if self.ceilings_open_fraction > 0 and not self._builds("IfcCovering"):
            raise ConfigError(f"ceilings_open_fraction = {self.ceilings_open_fraction:g} does nothing at stage "
                              f"{self.name!r}: no ceiling is built yet; leave it out or use stage 'finished'")

    def _builds(self, ifc_class: str) -> bool:
        classes = self.kept_classes()
        return (classes is None or ifc_class in classes) and ifc_class not in self.exclude

    @property
    def is_bare(self) -> bool:
        """True when the stage changes nothing (the model as it is)."""
        return self == StageSettings()

    def kept_classes(self) -> tuple[str, ...] | None:
        """The IFC classes this stage builds (None: all), before ``exclude``."""
        return self.include if self.include else STAGES[self.name]


@dataclass(frozen=True)
class ClutterSettings(Checked):
    """Clutter and temporary works on the floors.

    density: objects per square metre of free floor (0 = none). kinds: kind names of the clutter
    library (``chair``, ``ceiling_light``, ``scaffold_tower``, ...) or groups (``office``,
    ``ceiling``, ``site``, ``people``); empty: chosen by the stage (``finished``: office furniture,
    fixtures under the ceilings and people; earlier stages: site items, temporary works and
    people). Ceiling kinds are laid out on a grid per room when the density is above 0, and not
    counted in it.
    """

    density: float = setting(0.0, within=Range(0.0, MAX_DENSITY_PER_M2),
                             hint="objects per square metre of free floor, 0: none")
    kinds: tuple[str, ...] = ()

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"clutter {problem}")

    def check(self) -> None:
        from bimscan.site.library import check_kinds

        check_kinds(self.kinds)


@dataclass(frozen=True)
class SiteModel(Checked):
    """What the site looks like when scanned: the construction stage, the clutter on the floors and
    the ground around the building (``ground_margin_m``: a flat terrain patch reaching this far
    beyond the footprint's bounding rectangle, at the ground floor's level; 0: none; a drone's
    flight adds its platform's) with site objects on it (``yard_density``: containers, stacks,
    pallets, bins, drums, scaffold towers per 100 m2 of it; ``site.ground``)."""

    stage: StageSettings = field(default_factory=StageSettings)
    clutter: ClutterSettings = field(default_factory=ClutterSettings)
    ground_margin_m: float = setting(0.0, within=Range(0.0, 1000.0), hint="metres around the footprint, 0: none")
    yard_density: float = setting(0.0, within=Range(0.0, 20.0), hint="objects per 100 m2 of ground, 0: none")

    def check(self) -> None:
        if self.clutter.kinds and self.clutter.density == 0.0:
            raise ConfigError(f"clutter kinds {', '.join(self.clutter.kinds)} are given with a clutter density of 0, "
                              "which places nothing; give a density (--clutter 0.3) or leave the kinds out")

    @property
    def is_bare(self) -> bool:
        """True when dressing changes nothing: the finished model, no clutter."""
        return (self.stage.is_bare and self.clutter.density == 0.0 and self.ground_margin_m == 0.0
                and self.yard_density == 0.0)

    @property
    def warnings(self) -> tuple[str, ...]:
        """Settings that do less than they seem to, one line each."""
        if self.stage.props_fraction > 0 and self.stage._builds("IfcCovering"):
            return (f"props_fraction = {self.stage.props_fraction:g} at stage {self.stage.name!r}: props stand only "
                    "where no ceiling hides the slab (rooms with exposed soffits); use stage 'structure' or "
                    "'enclosed' for propped slabs",)
        return ()

    def to_json(self) -> dict[str, Any]:
        """JSON-able (what clouds and units record; part of the recipe's fingerprint)."""
        stage = dataclasses.asdict(self.stage)
        stage["include"], stage["exclude"] = list(self.stage.include), list(self.stage.exclude)
        site = {"stage": stage, "clutter": {"density": self.clutter.density, "kinds": list(self.clutter.kinds)}}
        if self.ground_margin_m:  # only then: a site without ground records what it recorded before
            site["ground_margin_m"] = self.ground_margin_m
        if self.yard_density:
            site["yard_density"] = self.yard_density
        return site


def iso_date(value: Any) -> str:
    """A date as ISO ``YYYY-MM-DD`` (compared as text with the schedule's dates): from that text,
    ISO 8601's basic ``YYYYMMDD``, a TOML date or a datetime (its day). ConfigError otherwise."""
    if isinstance(value, datetime.datetime):
        return value.date().isoformat()
    if isinstance(value, datetime.date):
        return value.isoformat()
    text = value.strip() if isinstance(value, str) else None
    try:
        extended = text is not None and len(text) == 10 and text[4] == "-" and text[7] == "-"
        basic = text is not None and len(text) == 8 and text.isdigit()  # ISO 8601's basic form, 20240310
        if not (extended or basic):
            raise ValueError(text)
        return datetime.date.fromisoformat(text).isoformat()
    except ValueError as exc:
        raise ConfigError(f"at = {value!r} is not a date; give one as YYYY-MM-DD (e.g. 2024-03-10)") from exc


def ifc_product_classes(names: Any, *, what: str) -> tuple[str, ...]:
    """``names`` (IFC class names, any case) in the schemas' spelling; ConfigError, naming the nearest
    class, for a name that is no ``IfcProduct`` class of IFC2X3, IFC4 or IFC4X3 (a typo such as
    ``IfcDoors`` would otherwise match nothing and change nothing). ``what`` names the list."""
    if not isinstance(names, list | tuple) or not names:
        return names
    from bimscan.ifc.schema import known_classes, nearest_product_class, product_classes

    spelt = []
    for name in names:
        if not isinstance(name, str):
            raise ConfigError(f"{what} entry {name!r} is not an IFC class name; give names like 'IfcWall'")
        product = product_classes().get(name.lower())
        if product is None:
            if name.lower() in {k.lower() for k in known_classes()}:
                raise ConfigError(f"{what}: {name!r} is an IFC class but no product (IfcProduct): nothing of it "
                                  "stands in a scene; give classes of elements such as 'IfcWall'")
            nearest = nearest_product_class(name)
            advice = f"did you mean {nearest!r}?" if nearest else "give classes of elements such as 'IfcWall'"
            raise ConfigError(f"{what}: unknown IFC class {name!r} (no IfcProduct class of IFC2X3, IFC4 or "
                              f"IFC4X3); {advice}")
        spelt.append(product)
    return tuple(spelt)


def site_settings(site: SiteModel, seed: int) -> dict[str, Any]:
    """What a dressed scene depends on besides the model: the site model and the seed."""
    return {"site": site.to_json(), "seed": seed}


def stage_table(value: Any) -> Any:
    """A TOML ``stage`` value as a table: a bare name (``"structure"``) is ``{name = ...}``."""
    return {"name": value} if isinstance(value, str) else value


def site_from_mapping(data: Mapping[str, Any], *, where: str) -> SiteModel:
    """A SiteModel from TOML-like data (``stage`` as a name or a table, ``clutter`` a table)."""
    from bimscan.toml_files import build_dataclass

    data = dict(data)
    if "stage" in data:
        data["stage"] = stage_table(data["stage"])
    return build_dataclass(SiteModel, data, where=where)
