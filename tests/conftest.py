"""Shared test fixtures: paths to the shared sample models, a private geometry cache."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# CI runs the same hypothesis examples every time (a failure is reproducible, never a coin toss);
# HYPOTHESIS_PROFILE=explore draws new ones, as a search for bugs.
settings.register_profile("ci", derandomize=True, deadline=None)
settings.register_profile("explore", deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

SHARED_IFC = Path(__file__).resolve().parents[2] / "shared" / "data" / "ifc"


def shared_model(name: str) -> Path:
    """Path of a shared sample IFC model; skips the test when the shared folder is absent."""
    path = SHARED_IFC / name
    if not path.is_file():
        pytest.skip(f"shared sample model {path} is absent (needs ../shared/data/ifc beside the checkout)")
    return path


@pytest.fixture
def shared_ifc():
    """``shared_ifc("duplex.ifc")``: path of a shared sample model, or skip with the reason."""
    return shared_model


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every test session gets its own geometry cache, so tests never see a stale user cache."""
    cache = tmp_path_factory.getbasetemp() / "bimscan-cache"
    monkeypatch.setenv("BIMSCAN_CACHE_DIR", str(cache))
    return cache


class TinyModel:
    """A small IFC model built with ifcopenshell.api (as IfcOpenShell's own tests do)."""

    def __init__(self, schema: str = "IFC4") -> None:
        import ifcopenshell
        import ifcopenshell.api
        import ifcopenshell.api.geometry  # noqa: F401  (registers the geometry api)

        self.api = ifcopenshell.api
        self.file = ifcopenshell.file(schema=schema)
        run = self.api.run
        if schema == "IFC2X3":  # IFC2X3 requires an owner history on every rooted entity
            import ifcopenshell.api.owner.settings as owner

            person = self.file.createIfcPerson(FamilyName="Tester")
            organisation = self.file.createIfcOrganization(Name="bimscan")
            user = self.file.createIfcPersonAndOrganization(person, organisation)
            application = self.file.createIfcApplication(organisation, "1", "bimscan tests", "bimscan-tests")
            owner.get_user = lambda f: user
            owner.get_application = lambda f: application
        project = run("root.create_entity", self.file, ifc_class="IfcProject", name="tiny")
        metre = run("unit.add_si_unit", self.file, unit_type="LENGTHUNIT")
        run("unit.assign_unit", self.file, units=[metre])
        model = run("context.add_context", self.file, context_type="Model")
        self.body = run("context.add_context", self.file, context_type="Model", context_identifier="Body",
                        target_view="MODEL_VIEW", parent=model)
        site = run("root.create_entity", self.file, ifc_class="IfcSite", name="site")
        run("aggregate.assign_object", self.file, relating_object=project, products=[site])
        building = run("root.create_entity", self.file, ifc_class="IfcBuilding", name="building")
        run("aggregate.assign_object", self.file, relating_object=site, products=[building])
        self.storey = run("root.create_entity", self.file, ifc_class="IfcBuildingStorey", name="L0")
        run("aggregate.assign_object", self.file, relating_object=building, products=[self.storey])

    def add_storey(self, name: str, elevation: float):
        """Another building storey at ``elevation`` metres (the first, "L0", stands at 0)."""
        import numpy as np

        run = self.api.run
        building = self.file.by_type("IfcBuilding")[0]
        storey = run("root.create_entity", self.file, ifc_class="IfcBuildingStorey", name=name)
        storey.Elevation = float(elevation)
        run("aggregate.assign_object", self.file, relating_object=building, products=[storey])
        matrix = np.eye(4)
        matrix[2, 3] = elevation
        run("geometry.edit_object_placement", self.file, product=storey, matrix=matrix)
        return storey

    def add_box(self, ifc_class: str, *, origin=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0), predefined_type: str | None = None,
                name: str | None = None, contain: bool = True, storey=None, tilt_deg: float = 0.0):
        """An element with an extruded rectangle body of ``size`` (metres) at ``origin`` (world),
        tilted by ``tilt_deg`` about the y axis through ``origin`` (a pitched roof), contained in
        ``storey`` (default: the first); an IfcSpace is aggregated into it instead."""
        import numpy as np

        run = self.api.run
        element = run("root.create_entity", self.file, ifc_class=ifc_class, name=name, predefined_type=predefined_type)
        f = self.file
        profile = f.createIfcRectangleProfileDef("AREA", None, f.createIfcAxis2Placement2D(
            f.createIfcCartesianPoint((size[0] / 2, size[1] / 2)), None), size[0], size[1])
        placement = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
        solid = f.createIfcExtrudedAreaSolid(profile, placement, f.createIfcDirection((0.0, 0.0, 1.0)), size[2])
        rep = f.createIfcShapeRepresentation(self.body, "Body", "SweptSolid", [solid])
        run("geometry.assign_representation", f, product=element, representation=rep)
        matrix = np.eye(4)
        matrix[:3, 3] = origin
        if tilt_deg:
            c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
            matrix[:3, :3] = [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
        run("geometry.edit_object_placement", f, product=element, matrix=matrix)
        if contain and element.is_a("IfcSpace"):
            run("aggregate.assign_object", f, relating_object=storey or self.storey, products=[element])
        elif contain:
            run("spatial.assign_container", f, relating_structure=storey or self.storey, products=[element])
        return element

    def add_broken(self, ifc_class: str = "IfcColumn"):
        """An element whose body cannot be triangulated (a degenerate profile)."""
        f = self.file
        element = self.api.run("root.create_entity", f, ifc_class=ifc_class)
        line = f.createIfcPolyline([f.createIfcCartesianPoint((0.0, 0.0)), f.createIfcCartesianPoint((0.0, 0.0))])
        profile = f.createIfcArbitraryClosedProfileDef("AREA", None, line)
        solid = f.createIfcExtrudedAreaSolid(profile, None, f.createIfcDirection((0.0, 0.0, 1.0)), 3.0)
        rep = f.createIfcShapeRepresentation(self.body, "Body", "SweptSolid", [solid])
        element.Representation = f.createIfcProductDefinitionShape(None, None, [rep])
        self.api.run("spatial.assign_container", f, relating_structure=self.storey, products=[element])
        return element

    def write(self, path: Path) -> Path:
        self.file.write(str(path))
        return path


@pytest.fixture(scope="session")
def tiny_model():
    """Factory for TinyModel: ``tiny_model(schema="IFC2X3")`` (the class: usable from fixtures of any scope)."""
    return TinyModel


BOX_ROOM = {"size": (8.0, 6.0, 3.5), "wall": 0.25, "slab": 0.3}


def build_box_room(path: Path, *, schema: str = "IFC4") -> Path:
    """A closed room 8 x 6 x 3.5 m (inside), floor top at z = 0: 2 slabs and 4 walls."""
    sx, sy, sz = BOX_ROOM["size"]
    w, s = BOX_ROOM["wall"], BOX_ROOM["slab"]
    model = TinyModel(schema)
    model.add_box("IfcSlab", origin=(-w, -w, -s), size=(sx + 2 * w, sy + 2 * w, s), predefined_type="FLOOR", name="floor")
    model.add_box("IfcSlab", origin=(-w, -w, sz), size=(sx + 2 * w, sy + 2 * w, s), predefined_type="ROOF", name="roof")
    model.add_box("IfcWall", origin=(-w, -w, 0.0), size=(sx + 2 * w, w, sz), name="south")
    model.add_box("IfcWall", origin=(-w, sy, 0.0), size=(sx + 2 * w, w, sz), name="north")
    model.add_box("IfcWall", origin=(-w, 0.0, 0.0), size=(w, sy, sz), name="west")
    model.add_box("IfcWall", origin=(sx, 0.0, 0.0), size=(w, sy, sz), name="east")
    return model.write(path)


@pytest.fixture(scope="session")
def box_room_ifc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of the closed box room IFC (built once per test session)."""
    return build_box_room(tmp_path_factory.mktemp("box") / "box_room.ifc")
