"""Loading IFC (load_ifc, labelled by load_scene) on generated demo buildings: what the generator placed is what the loader finds."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from bimscan.ifc.generate import make_building
from bimscan.pipeline import load_scene

EXPECTED_LABEL = {"IfcWall": "Wall&Column", "IfcColumn": "Wall&Column", "IfcBeam": "Beam",
                  "IfcCovering": "Covering", "IfcSlab": "Slab"}


@pytest.mark.parametrize("seed, storeys", [(0, 1), (3, 2), (11, 3)])
def test_generated_buildings_load_with_the_placed_counts_labels_and_bounds(seed, storeys, tmp_path):
    building = make_building(tmp_path / "b.ifc", seed=seed, storeys=storeys)
    scene = load_scene(building.path, strict=True)  # the generator writes files nothing needs repairing in
    assert scene.failed == () and scene.report.clean
    assert scene.report.declared_elements == len(scene.components)
    assert dict(Counter(scene.components.ifc_class.tolist())) == dict(building.placed)
    names = scene.scheme.names
    for ifc_class, label in zip(scene.components.ifc_class.tolist(), scene.components.label.tolist()):
        expected = EXPECTED_LABEL.get(ifc_class, "Others")
        if ifc_class == "IfcSlab":
            assert names[label] == "Slab"
        else:
            assert names[label] == expected, ifc_class
    assert set(names[i] for i in scene.components.label.tolist()) == set(names.values())  # all five classes
    lo, hi = scene.mesh.bounds()
    xmin, ymin, xmax, ymax = building.footprint_m
    np.testing.assert_allclose([lo[0], lo[1], hi[0], hi[1]], [xmin, ymin, xmax, ymax], atol=0.05)
    assert hi[2] == pytest.approx(building.height_m, abs=0.01)
    assert [len([s for s in scene.spaces if s.storey == st.name]) for st in scene.storeys] == list(building.rooms_per_storey)
