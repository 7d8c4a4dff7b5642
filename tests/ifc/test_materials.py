"""Surface styles and materials of components: read from the shared models' IFC text, kept by the cache."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.ifc.load import load_ifc
from bimscan.ifc.materials import read_surfaces


def surfaces_of(path, global_ids):
    """The surfaces of the named elements, read straight from the file (no triangulation)."""
    import ifcopenshell

    model = ifcopenshell.open(str(path))
    return read_surfaces([model.by_guid(g) for g in global_ids])


def test_a_duplex_window_takes_its_sash_colour_and_its_glazing_transparency(shared_ifc):
    # duplex.ifc: #6321 IFCCOLOURRGB(0.878.., 0.698.., 0.494..) in style 'Sash' (transparency 0);
    # #6300 (0, 0.502, 0.753) in style 'Glass' with transparency 0.9 on the same window's glazing
    window, beam = "1hOSvn6df7F8_7GcBWlR72", "2OrWItJ6zAwBNp0OUxK_l8"
    surfaces = surfaces_of(shared_ifc("duplex.ifc"), [window, beam])
    np.testing.assert_allclose(surfaces.color[0], [0.8784314, 0.6980392, 0.4941176], atol=1e-6)
    assert surfaces.transparency[0] == pytest.approx(0.9, abs=1e-6)
    assert surfaces.style[0] == "Sash"
    assert surfaces.style[1] == "Metal - Steel - 345 MPa" and surfaces.material[1] == "Metal - Steel - 345 MPa"
    assert surfaces.transparency[1] == 0.0


def test_a_duplex_windows_glazing_triangles_are_transparent_and_its_sash_triangles_are_not(shared_ifc):
    # duplex.ifc: the window's items carry style 'Glass' (transparency 0.9) or 'Sash' (0); IfcOpenShell
    # resolves them per triangle
    parsed = load_ifc(shared_ifc("duplex.ifc"))
    window = int(np.flatnonzero(parsed.components.global_id == "1hOSvn6df7F8_7GcBWlR72")[0])
    alpha = parsed.mesh.face_transparency[parsed.mesh.face_component == window]
    assert set(np.round(alpha.astype(np.float64), 6).tolist()) == {0.9, 0.0}
    assert 0 < (alpha > 0).sum() < (alpha == 0).sum()  # the panes are a few large triangles, the sash many


def test_an_fzk_haus_slab_is_concrete_grey_and_names_its_material(shared_ifc):
    # AC20-FZK-Haus.ifc: style 'Beton' #34486 IFCCOLOURRGB(0.549019607843, 0.552941176471, 0.494117647059)
    surfaces = surfaces_of(shared_ifc("AC20-FZK-Haus.ifc"), ["1pPHnf7cXCpPsNEnQf8_6B"])
    np.testing.assert_allclose(surfaces.color[0], [0.549019607843, 0.552941176471, 0.494117647059], atol=1e-6)
    assert surfaces.style[0] == "Beton" and surfaces.material[0] == "Stahlbeton 65690"


def test_load_ifc_keeps_surfaces_per_component_and_the_cache_returns_them(shared_ifc):
    # IfcOpenHouse_IFC4.ifc: the glass plates are #2588.. IFCCOLOURRGB(0.6, 0.7, 0.75), Transparency 0.9;
    # walls #66 IFCCOLOURRGB(0.75, 0.73, 0.68), opaque, material 'Brick'
    path = shared_ifc("IfcOpenHouse_IFC4.ifc")
    parsed = load_ifc(path)
    cached = load_ifc(path)
    surfaces = parsed.surfaces
    assert surfaces is not None and len(surfaces) == len(parsed.components)
    plates = parsed.components.ifc_class == "IfcPlate"
    walls = parsed.components.ifc_class == "IfcWallStandardCase"
    np.testing.assert_allclose(surfaces.color[plates], np.tile([0.6, 0.7, 0.75], (plates.sum(), 1)), atol=1e-6)
    np.testing.assert_allclose(surfaces.transparency[plates], 0.9, atol=1e-6)
    np.testing.assert_allclose(surfaces.color[walls], np.tile([0.75, 0.73, 0.68], (walls.sum(), 1)), atol=1e-6)
    assert (surfaces.transparency[walls] == 0).all() and set(surfaces.material[walls]) == {"Brick"}
    for column in ("color", "transparency", "style", "material"):
        np.testing.assert_array_equal(getattr(cached.surfaces, column), getattr(surfaces, column))


def test_an_element_without_any_style_has_no_colour_and_is_opaque(tiny_model, tmp_path):
    import ifcopenshell.api.style  # noqa: F401

    model = tiny_model("IFC4")
    plain = model.add_box("IfcWall", size=(4, 0.2, 3))
    styled = model.add_box("IfcSlab", origin=(0, 0, -0.3), size=(4, 4, 0.3))
    style = model.api.run("style.add_style", model.file, name="red glass")
    model.api.run("style.add_surface_style", model.file, style=style, ifc_class="IfcSurfaceStyleShading",
                  attributes={"SurfaceColour": {"Name": None, "Red": 1.0, "Green": 0.0, "Blue": 0.0},
                              "Transparency": 0.7})
    item = styled.Representation.Representations[0].Items[0]
    model.api.run("style.assign_item_style", model.file, item=item, style=style)
    parsed = load_ifc(model.write(tmp_path / "styled.ifc"))
    order = {g: i for i, g in enumerate(parsed.components.global_id)}
    surfaces = parsed.surfaces
    assert np.isnan(surfaces.color[order[plain.GlobalId]]).all() and surfaces.transparency[order[plain.GlobalId]] == 0
    np.testing.assert_allclose(surfaces.color[order[styled.GlobalId]], [1.0, 0.0, 0.0])
    assert surfaces.transparency[order[styled.GlobalId]] == pytest.approx(0.7)
    assert surfaces.style[order[styled.GlobalId]] == "red glass"
