"""Stage 3: semantic mapping of IFC classes onto label schemes (data files, not code)."""

from bimscan.semantics.scheme import (
    DEFAULT_SCHEME,
    ComponentLabels,
    builtin_schemes,
    check_rule_classes,
    label_model,
    load_scheme,
    map_labels,
    parse_scheme,
)

__all__ = [
    "DEFAULT_SCHEME", "ComponentLabels", "builtin_schemes", "check_rule_classes", "label_model", "load_scheme",
    "map_labels", "parse_scheme",
]
