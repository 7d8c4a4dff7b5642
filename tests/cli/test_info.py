"""``bimscan info``: report, JSON, one-line errors."""

from __future__ import annotations

import json

from bimscan.cli.main import main


def test_info_json_has_the_documented_fields(shared_ifc, capsys):
    assert main(["info", str(shared_ifc("duplex.ifc")), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    for key in ("schema", "components", "triangles", "by_ifc_class", "by_label", "failed", "bounds"):
        assert key in summary
    assert summary["schema"] == "IFC2X3"
    assert summary["components"] == sum(summary["by_ifc_class"].values()) == sum(summary["by_label"].values())
    assert summary["by_label"]["Beam"] == 8
    assert summary["fell_through_to_default"]["ifc_classes"] == {"IfcFooting": 7}
    assert all(lo < hi for lo, hi in zip(summary["bounds"]["min"], summary["bounds"]["max"]))


def test_info_report_lists_every_element_that_failed(tiny_model, tmp_path, capsys):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    model.add_broken("IfcColumn")
    assert main(["info", str(model.write(tmp_path / "m.ifc"))]) == 0
    out = capsys.readouterr().out
    assert "failed elements (1)" in out and "IfcColumn" in out


def test_info_errors_are_one_line_without_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.ifc"
    bad.write_text("hello")
    assert main(["info", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_every_command_has_help(capsys):
    from bimscan.cli.commands import cli

    for name in cli.commands:
        assert main([name, "--help"]) == 0
    assert main(["--help"]) == 0
    assert "Usage" in capsys.readouterr().out


def test_export_obj_round_trips_triangles_per_component(shared_ifc, tmp_path, capsys):
    import csv

    import numpy as np

    from bimscan.pipeline import load_scene
    from bimscan.io import read_obj

    model = shared_ifc("AC20-FZK-Haus.ifc")
    out = tmp_path / "obj"
    assert main(["export-obj", str(model), str(out), "--helios"]) == 0
    scene = load_scene(model)
    groups = read_obj(out / "model.obj")
    per_component = np.bincount(scene.mesh.face_component, minlength=len(scene.components))
    assert len(groups) == len(scene.components)
    for name, (_, faces) in groups.items():
        component = int(name.split("_")[0][1:])
        assert len(faces) == per_component[component]
        _, alone = next(iter(read_obj(out / "components" / f"c{component}.obj").values()))
        assert len(alone) == per_component[component]
    rows = list(csv.DictReader((out / "index.csv").open()))
    assert [r["global_id"] for r in rows] == scene.components.global_id.tolist()
    assert (out / "helios" / "scene.xml").is_file()
    assert main(["export-obj", str(model), str(out)]) == 1  # refuses to overwrite silently
    assert "already holds" in capsys.readouterr().err
