"""Label schemes: semantic classes and the rules mapping IFC classes onto them (data, not code).

A scheme is a TOML file (see ``schemes/spc5.toml``, the default: the SPC paper's five classes)::

    name = "my-scheme"
    default = "Other"              # class for everything no rule matches
    [[classes]]                    # ids 0..255 (LAS classification is one byte)
    id = 0
    name = "Wall"
    color = "#4e79a7"
    [[rules]]
    ifc_class = "IfcWall"          # matches IfcWall and all its subclasses
    label = "Wall"
    predefined_types = ["SHEAR"]   # optional: any of these PredefinedType values
    parent_class = "IfcCurtainWall"  # optional: only parts of such an aggregate

Rule precedence: more filters first, then the rule on the nearest ancestor class, then file order.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Collection, Mapping
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.toml_files import load_toml
from bimscan.errors import SchemeError
from bimscan.types import BimScene, ComponentTable, LabelClass, LabelRule, LabelScheme, ParsedModel

DEFAULT_SCHEME = "spc5"
_COLOR = re.compile(r"^#[0-9a-fA-F]{6}$")


def builtin_schemes() -> list[str]:
    """Names of the schemes shipped with bimscan."""
    folder = resources.files("bimscan.semantics") / "schemes"
    return sorted(p.name.removesuffix(".toml") for p in folder.iterdir() if p.name.endswith(".toml"))


def load_scheme(source: str | Path | None = None) -> LabelScheme:
    """Load a label scheme: None -> the default, a built-in name, or a TOML file path."""
    if source is None:
        source = DEFAULT_SCHEME
    if isinstance(source, str) and source in builtin_schemes():
        text = (resources.files("bimscan.semantics") / "schemes" / f"{source}.toml").read_text("utf-8")
        import tomllib

        return parse_scheme(tomllib.loads(text), where=f"built-in scheme {source!r}")
    path = Path(source)
    if not path.exists():
        raise SchemeError(
            f"label scheme {str(source)!r} is neither a file nor a built-in scheme "
            f"({', '.join(builtin_schemes())}); pass a TOML file"
        )
    return parse_scheme(load_toml(path), where=str(path))


def parse_scheme(data: Mapping[str, Any], *, where: str) -> LabelScheme:
    """Validate a scheme mapping (as read from TOML) into a LabelScheme."""
    allowed = {"name", "description", "default", "classes", "rules"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise SchemeError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(sorted(allowed))}")
    name = data.get("name", Path(where).stem)
    if not isinstance(name, str) or not name:
        raise SchemeError(f"{where}: 'name' must be a non-empty string, got {name!r}")
    raw_classes = data.get("classes")
    if not isinstance(raw_classes, list) or not raw_classes:
        raise SchemeError(f"{where}: needs at least one [[classes]] entry with id, name and color")
    classes = []
    for i, entry in enumerate(raw_classes):
        at = f"{where} [[classes]] #{i + 1}"
        if not isinstance(entry, Mapping):
            raise SchemeError(f"{at}: expected a table, got {entry!r}")
        extra = sorted(set(entry) - {"id", "name", "color"})
        if extra:
            raise SchemeError(f"{at}: unknown key(s) {', '.join(map(repr, extra))}; allowed: color, id, name")
        cid, cname, color = entry.get("id"), entry.get("name"), entry.get("color", "#7f7f7f")
        if isinstance(cid, bool) or not isinstance(cid, int) or not 0 <= cid <= 255:
            raise SchemeError(f"{at}: 'id' must be an integer in 0..255 (one LAS classification byte), got {cid!r}")
        if not isinstance(cname, str) or not cname.strip():
            raise SchemeError(f"{at}: 'name' must be a non-empty string, got {cname!r}")
        if not isinstance(color, str) or not _COLOR.match(color):
            raise SchemeError(f"{at}: 'color' must look like \"#rrggbb\", got {color!r}")
        classes.append(LabelClass(id=cid, name=cname, color=color.lower()))
    for what, values in (("id", [c.id for c in classes]), ("name", [c.name for c in classes])):
        dupes = sorted(str(v) for v, n in Counter(values).items() if n > 1)
        if dupes:
            raise SchemeError(f"{where}: class {what}(s) {', '.join(dupes)} appear more than once; make them unique")
    names = {c.name for c in classes}
    default = data.get("default")
    if default not in names:
        raise SchemeError(f"{where}: 'default' must name one of the classes ({', '.join(sorted(names))}), got {default!r}")
    rules = []
    for i, entry in enumerate(data.get("rules", [])):
        at = f"{where} [[rules]] #{i + 1}"
        if not isinstance(entry, Mapping):
            raise SchemeError(f"{at}: expected a table, got {entry!r}")
        extra = sorted(set(entry) - {"ifc_class", "label", "predefined_types", "parent_class"})
        if extra:
            raise SchemeError(f"{at}: unknown key(s) {', '.join(map(repr, extra))}; allowed: ifc_class, label, parent_class, predefined_types")
        ifc_class, label = entry.get("ifc_class"), entry.get("label")
        if not isinstance(ifc_class, str) or not ifc_class.startswith("Ifc"):
            raise SchemeError(f"{at}: 'ifc_class' must be an IFC class name like \"IfcWall\", got {ifc_class!r}")
        if label not in names:
            raise SchemeError(f"{at}: 'label' {label!r} is not one of the classes ({', '.join(sorted(names))})")
        types_ = entry.get("predefined_types", [])
        if not isinstance(types_, list) or not all(isinstance(t, str) and t for t in types_):
            raise SchemeError(f"{at}: 'predefined_types' must be a list of strings, got {types_!r}")
        parent = entry.get("parent_class")
        if parent is not None and (not isinstance(parent, str) or not parent.startswith("Ifc")):
            raise SchemeError(f"{at}: 'parent_class' must be an IFC class name, got {parent!r}")
        rules.append(LabelRule(ifc_class=ifc_class, label=label, predefined_types=tuple(t.upper() for t in types_), parent_class=parent))
    return LabelScheme(name=name, classes=tuple(classes), rules=tuple(rules), default_label=default)


def check_rule_classes(scheme: LabelScheme, known_classes: Collection[str]) -> None:
    """Raise SchemeError for rule classes that no IFC schema knows (usually a typo)."""
    known = {k.lower(): k for k in known_classes}
    for rule in scheme.rules:
        for cls in filter(None, (rule.ifc_class, rule.parent_class)):
            if cls.lower() not in known:
                raise SchemeError(f"label scheme {scheme.name!r}: unknown IFC class {cls!r} in a rule; check the spelling (e.g. 'IfcWall')")


@dataclass(frozen=True)
class LabelMapping:
    """Result of mapping components onto a scheme.

    labels: (C,) uint8 class id per component; unmapped: IFC class -> number of components that
    no rule matched (they got the default class).
    """

    labels: np.ndarray
    unmapped: dict[str, int]


def map_labels(components: ComponentTable, scheme: LabelScheme) -> LabelMapping:
    """Class id of every component under ``scheme``, and the IFC classes that fell through."""
    ids = {c.name: c.id for c in scheme.classes}
    default = ids[scheme.default_label]
    cache: dict[tuple[str, str, str], int | None] = {}
    labels = np.empty(len(components), dtype=np.uint8)
    unmapped: Counter[str] = Counter()
    for i in range(len(components)):
        key = (str(components.ifc_class[i]), str(components.predefined_type[i]).upper(), str(components.parent_class[i]))
        if key not in cache:
            cache[key] = _match(key, components.class_ancestry, scheme, ids)
        label = cache[key]
        if label is None:
            unmapped[key[0]] += 1
            label = default
        labels[i] = label
    return LabelMapping(labels=labels, unmapped=dict(sorted(unmapped.items())))


def _ancestry(cls: str, class_ancestry: Mapping[str, tuple[str, ...]]) -> tuple[str, ...]:
    return tuple(a.lower() for a in class_ancestry.get(cls, (cls,)))


def _match(key: tuple[str, str, str], class_ancestry: Mapping[str, tuple[str, ...]], scheme: LabelScheme, ids: dict[str, int]) -> int | None:
    ifc_class, predefined, parent = key
    chain = _ancestry(ifc_class, class_ancestry)
    parent_chain = _ancestry(parent, class_ancestry) if parent else ()
    best: tuple[int, int, int] | None = None
    best_label = None
    for order, rule in enumerate(scheme.rules):
        target = rule.ifc_class.lower()
        if target not in chain:
            continue
        if rule.predefined_types and predefined not in rule.predefined_types:
            continue
        if rule.parent_class and rule.parent_class.lower() not in parent_chain:
            continue
        filters = bool(rule.predefined_types) + bool(rule.parent_class)
        rank = (-filters, chain.index(target), order)
        if best is None or rank < best:
            best, best_label = rank, ids[rule.label]
    return best_label


def label_model(model: ParsedModel, scheme: LabelScheme) -> BimScene:
    """Stage 3 applied to stage 1's output: every component of ``model`` labelled under ``scheme``."""
    mapping = map_labels(model.components, scheme)
    return BimScene(
        source=model.source, file_sha256=model.file_sha256, schema=model.schema, mesh=model.mesh,
        components=replace(model.components, label=mapping.labels), scheme=scheme, storeys=model.storeys,
        spaces=model.spaces, failed=model.failed, unmapped_classes=mapping.unmapped, report=model.report,
    )
