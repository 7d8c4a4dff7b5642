"""``bimscan scan`` with a site: clutter as labelled components, construction stages, dates."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.io import read_cloud, read_cloud_header

FAST = ["--preset", "exp1", "--head-speed", "120"]


@pytest.fixture(scope="module")
def office_ifc(tmp_path_factory):
    from bimscan.ifc.generate import make_building

    return make_building(tmp_path_factory.mktemp("office") / "office.ifc", seed=2, storeys=1).path


def test_clutter_is_scanned_as_labelled_components_and_recorded(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "room.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--clutter", "0.3", "--clutter-kinds", "site"]) == 0
    report = capsys.readouterr().out
    assert "site: 0 components not built; placed" in report
    header, cloud = read_cloud_header(out), read_cloud(out)
    site_rows = np.flatnonzero(np.char.find(header.components.ifc_class.astype(str), ".") > 0)
    assert len(site_rows) == sum(header.metadata["site_state"]["placed"].values()) >= 5
    assert header.metadata["site"]["clutter"] == {"density": 0.3, "kinds": ["site"]}
    on_clutter = np.isin(cloud.component, site_rows)
    assert on_clutter.sum() > 1000  # the scanner sees them
    assert set(np.unique(cloud.label[on_clutter])) == {4}  # Others
    assert np.array_equal(cloud.label, header.components.label[cloud.component])


def test_the_structure_stage_scans_no_coverings_doors_windows_or_furniture(office_ifc, tmp_path):
    out = tmp_path / "structure.laz"
    assert main(["scan", str(office_ifc), str(out), *FAST, "--stage", "structure"]) == 0
    header, cloud = read_cloud_header(out), read_cloud(out)
    assert not {"IfcCovering", "IfcDoor", "IfcWindow", "IfcFurniture"} & set(header.components.ifc_class.tolist())
    assert set(np.unique(cloud.label)) <= {0, 1, 3}  # walls and columns, beams, slabs
    assert header.metadata["site_state"]["removed"]["IfcCovering"] > 0


def test_a_date_keeps_what_the_schedule_has_built(tmp_path, tiny_model):
    from tests.ifc.test_schedule import scheduled_room

    path, gids = scheduled_room(tmp_path / "scheduled.ifc", tiny_model)
    seen = {}
    for at in ("2024-03-20", "2024-06-01"):
        out = tmp_path / f"{at}.laz"
        assert main(["scan", str(path), str(out), *FAST, "--at", at]) == 0
        header = read_cloud_header(out)
        seen[at] = set(header.components.global_id.tolist())
    assert gids["A"] in seen["2024-03-20"] and gids["B"] not in seen["2024-03-20"] and gids["C"] in seen["2024-03-20"]
    assert gids["B"] in seen["2024-06-01"] and gids["C"] not in seen["2024-06-01"]


@pytest.mark.parametrize("flags, message", [
    (["--clutter", "-1"], ("clutter density must be a number in [0, 2] (objects per square metre of free floor, 0: "
                           "none), got -1")),
    (["--clutter", "0.2", "--clutter-kinds", "piano"], "unknown clutter kind 'piano'"),
    (["--at", "2024-01-01"], "links no element to a dated task"),
    (["--walls-missing", "2"], "stage walls_missing_fraction must be a number in [0, 1], got 2"),
])
def test_impossible_site_flags_are_one_line_errors_and_write_nothing(box_room_ifc, tmp_path, capsys, flags, message):
    out = tmp_path / "room.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, *flags]) == 1
    *warnings, error = capsys.readouterr().err.splitlines()
    assert error.startswith("error: ") and message in error
    assert all(w.startswith("warning: ") for w in warnings)  # the preset's device warnings
    assert not out.exists() and not list(tmp_path.iterdir())


@pytest.mark.parametrize("command, flags, message", [
    ("scan", ["--stage-exclude", "IfcDoors"], "stage exclude: unknown IFC class 'IfcDoors'"),
    ("plan", ["--stage-include", "IfcWall,IfcFoo"], "stage include: unknown IFC class 'IfcFoo'"),
    ("export-obj", ["--stage-exclude", "IfcWindows"], "did you mean 'IfcWindow'?"),
])
def test_a_misspelt_stage_class_is_refused_naming_the_nearest_before_the_model_is_read(command, flags, message,
                                                                                      tmp_path, capsys):
    # the model does not exist: the flags are refused before any work, reading the model included
    assert main([command, str(tmp_path / "missing.ifc"), str(tmp_path / "out"), *flags]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
    assert not list(tmp_path.iterdir())
