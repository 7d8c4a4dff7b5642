"""Stage 3b: the scene as the site looks when scanned (construction stage, clutter, temporary works).

``dress_scene(scene, site, seed=...)`` takes a labelled ``BimScene`` and a ``SiteModel`` (the
``site`` field of a ``ScanRecipe``) and returns the scene at that construction stage with
clutter and temporary works placed on its floors as new, labelled components. Pure functions
over the shared types; ray probes go through the scan engine interface.
"""

from bimscan.site.classes import SITE_CLASSES, site_class_names
from bimscan.site.dress import DressTimings, default_kinds, dress_scene, dress_scene_timed
from bimscan.site.library import CLUTTER_KINDS, GROUPS
from bimscan.site.model import STAGES, ClutterSettings, SiteModel, StageSettings, site_from_mapping, site_settings

__all__ = [
    "CLUTTER_KINDS", "GROUPS", "SITE_CLASSES", "STAGES", "ClutterSettings", "DressTimings", "SiteModel",
    "StageSettings",
    "default_kinds", "dress_scene", "dress_scene_timed", "site_class_names", "site_from_mapping",
    "site_settings",
]
