"""The stages composed: every check that can fail runs before the slow work."""

from __future__ import annotations

import pytest

import bimscan.pipeline as pipeline
from bimscan.errors import ConfigError, StationError
from bimscan.pipeline import load_scene, scan_model, site_and_stations
from bimscan.survey.recipe import ScanRecipe
from bimscan.site.model import ClutterSettings, SiteModel, StageSettings


@pytest.fixture
def no_dressing(monkeypatch):
    """Dressing the site fails the test: what is checked must fail before it starts."""
    def dress(*args, **kwargs):
        raise AssertionError("the dressing started before the check failed")

    monkeypatch.setattr(pipeline, "dress_scene_timed", dress)


def test_a_bad_station_file_fails_before_the_dressing_starts(box_room_ifc, tmp_path, no_dressing):
    stations = tmp_path / "stations.csv"
    stations.write_text("x,y,z\n4,3,1.7\n8.1,3,1.7\n")  # the second inside the east wall
    recipe = ScanRecipe(stations_from=str(stations), site=SiteModel(clutter=ClutterSettings(density=0.8)))
    with pytest.raises(StationError, match="station 1 .* inside a solid"):
        site_and_stations(load_scene(box_room_ifc), recipe)


def test_a_model_where_no_tripod_stands_fails_before_the_dressing_starts(tiny_model, tmp_path, no_dressing):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", origin=(0.0, 0.0, 0.0), size=(6.0, 0.2, 3.0))  # a wall on its own
    recipe = ScanRecipe(site=SiteModel(clutter=ClutterSettings(density=0.8)))
    with pytest.raises(StationError, match="no place for a station"):
        site_and_stations(load_scene(model.write(tmp_path / "wall.ifc")), recipe)


def test_a_date_without_a_work_schedule_fails_before_the_dressing_starts(box_room_ifc, no_dressing):
    recipe = ScanRecipe(site=SiteModel(stage=StageSettings(at="2024-05-01"), clutter=ClutterSettings(density=0.5)))
    with pytest.raises(ConfigError, match="links no element to a dated task"):
        site_and_stations(load_scene(box_room_ifc), recipe)


@pytest.mark.parametrize("written, read", [("2024-03-10", "2024-03-10"), ("20240310", "2024-03-10"),
                                           (" 2024-03-10 ", "2024-03-10")])
def test_dates_are_read_as_iso_dates_whatever_their_form(written, read):
    assert StageSettings(at=written).at == read


@pytest.mark.parametrize("written", ["2024-3-10", "10.03.2024", "next week", "2024031"])
def test_text_that_is_not_a_date_is_refused_in_one_line(written):
    with pytest.raises(ConfigError, match="YYYY-MM-DD"):
        StageSettings(at=written)


def test_a_toml_date_in_a_spec_is_read_as_a_date():
    import tomllib

    from bimscan.site.model import site_from_mapping

    site = site_from_mapping(tomllib.loads('stage = { name = "structure", at = 2024-05-01 }'), where="spec")
    assert site.stage.at == "2024-05-01"


def test_settings_that_do_nothing_are_refused_or_warned_of(box_room_ifc, tmp_path):
    with pytest.raises(ConfigError, match="does nothing at stage 'structure'"):
        StageSettings(name="structure", ceilings_open_fraction=0.5)
    with pytest.raises(ConfigError, match="places nothing"):
        SiteModel(clutter=ClutterSettings(kinds=("chair",)))
    warned: list[str] = []
    recipe = ScanRecipe.resolve(head_deg_per_s=60.0, site=SiteModel(stage=StageSettings(props_fraction=0.5)))
    scan_model(box_room_ifc, tmp_path / "props.laz", recipe, progress=False, warn=warned.append)
    assert any("props stand only where no ceiling hides the slab" in line for line in warned)
