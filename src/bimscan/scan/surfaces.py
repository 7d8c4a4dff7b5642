"""What the laser and the camera see of each component: reflectance, transparency, colour.

The IFC stage reads the facts (``types.ComponentSurfaces``: style colour, transparency, style and
material names); this module interprets them for the scanner through a small material table
(``materials.toml``, replaceable with ``SensorModel.material_table``): each component gets a
category (first word match in its style name, then its material names, then its IFC class), the
category's near-infrared reflectance, the higher of its style's and its category's transparency,
and its style colour (else the category's colour).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError
from bimscan.toml_files import build_dataclass, load_toml
from bimscan.types import ComponentSurfaces

PAPER_REFLECTANCE = 0.5  # the reflectance every surface has when material reflectance is off


@dataclass(frozen=True)
class MaterialCategory(Checked):
    """One row of the material table (see ``materials.toml``)."""

    words: tuple[str, ...]
    reflectance: float = setting(within=Range(0.0, 1.0))
    color: tuple[float, float, float] = setting(each=Range(0.0, 1.0))
    transparency: float = setting(0.0, within=Range(0.0, 1.0))


@dataclass(frozen=True)
class MaterialTable:
    """Categories in matching order, IFC class fallbacks, the default category; ``name`` says where it came from."""

    name: str
    categories: dict[str, MaterialCategory]
    classes: dict[str, str]
    default: str

    def category_of(self, style: str, materials: str, ancestry: tuple[str, ...]) -> str:
        """The category of a component from its style name, material names and IFC class chain."""
        for text in (style, materials):
            lowered = text.lower()
            if lowered:
                for name, category in self.categories.items():
                    if any(word in lowered for word in category.words):
                        return name
        for cls in ancestry:
            if cls in self.classes:
                return self.classes[cls]
        return self.default


def _parse_table(data: dict, where: str, name: str) -> MaterialTable:
    data = dict(data)
    unknown = sorted(set(data) - {"default", "categories", "classes"})
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: default, categories, classes")
    raw = data.get("categories")
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{where}: no [categories.<name>] tables; give at least one category")
    categories = {}
    for key, table in raw.items():
        category = build_dataclass(MaterialCategory, table, where=f"{where} [categories.{key}]")
        categories[key] = MaterialCategory(words=tuple(w.lower() for w in category.words),
                                           reflectance=category.reflectance, color=category.color,
                                           transparency=category.transparency)
    classes = data.get("classes", {})
    if not isinstance(classes, dict) or not all(isinstance(v, str) for v in classes.values()):
        raise ConfigError(f"{where}: [classes] must map IFC class names to category names")
    default = data.get("default", "other")
    for target in [default, *classes.values()]:
        if target not in categories:
            raise ConfigError(f"{where}: category {target!r} is not defined; define [categories.{target}] or use one of "
                              f"{', '.join(categories)}")
    return MaterialTable(name=name, categories=categories, classes=dict(classes), default=default)


@lru_cache(maxsize=8)
def _load_cached(path: str | None, mtime_ns: int) -> MaterialTable:
    if path is None:
        text = (resources.files("bimscan.scan") / "materials.toml").read_text("utf-8")
        return _parse_table(tomllib.loads(text), "built-in materials.toml", "built-in")
    return _parse_table(load_toml(path), path, Path(path).name)


def load_material_table(path: str | Path | None = None) -> MaterialTable:
    """The built-in material table (None) or one from a TOML file with the same keys."""
    if path is None:
        return _load_cached(None, 0)
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"material table {str(path)!r} not found; pass a TOML file like bimscan/scan/materials.toml")
    return _load_cached(str(path.resolve()), path.stat().st_mtime_ns)


@dataclass(frozen=True)
class SurfaceTable:
    """Per component (C,): category name, NIR reflectance (float32), transparency (float32),
    colour (C, 3) float32 in 0..1."""

    category: np.ndarray
    reflectance: np.ndarray
    transparency: np.ndarray
    color: np.ndarray


def surface_table(surfaces: ComponentSurfaces | None, ifc_class: np.ndarray,
                  class_ancestry: dict[str, tuple[str, ...]], table: MaterialTable, *,
                  material_reflectance: bool) -> SurfaceTable:
    """Interpret the IFC facts of every component through ``table``.

    Without surfaces (a model built in memory) every component is categorised by its class.
    ``material_reflectance`` False: every reflectance is the paper's 0.5 (glass and colour only).
    """
    n = len(ifc_class)
    facts = surfaces if surfaces is not None else ComponentSurfaces.unknown(n)
    names = np.array([table.category_of(str(facts.style[i]), str(facts.material[i]),
                                        class_ancestry.get(str(ifc_class[i]), (str(ifc_class[i]),)))
                      for i in range(n)], dtype=str) if n else np.zeros(0, dtype="<U1")
    rows = [table.categories[str(c)] for c in names]
    reflectance = np.array([r.reflectance if material_reflectance else PAPER_REFLECTANCE for r in rows], dtype=np.float32)
    transparency = np.maximum(facts.transparency, np.array([r.transparency for r in rows], dtype=np.float32))
    fallback = np.array([r.color for r in rows], dtype=np.float32).reshape(n, 3)
    color = np.where(np.isnan(facts.color), fallback, facts.color).astype(np.float32)
    return SurfaceTable(category=names, reflectance=reflectance.reshape(n), transparency=transparency.astype(np.float32),
                        color=color)


def glazing_faces(component_transparency: np.ndarray, face_component: np.ndarray,
                  face_style_transparency: np.ndarray | None) -> np.ndarray:
    """(F,) float64: how much of the beam each triangle passes.

    A component passes its transparency (``SurfaceTable.transparency``) on every triangle, unless
    the model styles some of its triangles transparent and others not (a window's glazing apart
    from its frame and sash, as IfcOpenShell resolves each item's style): then only those pass it
    and the rest are opaque. ``face_style_transparency`` (F,): each triangle's own style
    transparency, NaN without a style (``SceneMesh.face_transparency``; None: not known).
    """
    alpha = np.asarray(component_transparency, dtype=np.float64)[face_component]
    if face_style_transparency is None:
        return alpha
    with np.errstate(invalid="ignore"):
        pane = np.asarray(face_style_transparency) > 0.0  # NaN (no style): not a pane
    has_panes = np.zeros(len(component_transparency), dtype=bool)
    has_panes[face_component[pane]] = True
    return np.where(has_panes[face_component] & ~pane, 0.0, alpha)
