"""``bimscan progress --model``: a segmentation model's Others points support no element."""

from __future__ import annotations

import json

import numpy as np

from bimscan.cli.main import main


def test_points_a_model_calls_others_support_nothing(box_room_ifc, trained_run, tmp_path):
    stations = tmp_path / "stations.csv"
    stations.write_text("x,y,height\n2.5,2.0,1.5\n")
    scan = tmp_path / "room.laz"
    assert main(["scan", str(box_room_ifc), str(scan), "--stations", str(stations), "--head-speed", "120",
                 "--no-noise"]) == 0
    checkpoint = trained_run / "run" / "last.pt"
    plain, segmented = tmp_path / "plain", tmp_path / "segmented"
    assert main(["progress", str(box_room_ifc), str(scan), str(plain), "--points", "none"]) == 0
    assert main(["progress", str(box_room_ifc), str(scan), str(segmented), "--points", "none", "--model",
                 str(checkpoint)]) == 0
    # the model's labels were work files only
    assert not any(p.name.startswith("labels") for p in segmented.iterdir())
    import csv

    rows = {name: {r["global_id"]: r for r in csv.DictReader((folder / "elements.csv").open())}
            for name, folder in (("plain", plain), ("segmented", segmented))}
    supported = {name: np.array([float(rows[name][g]["supported_share"]) for g in sorted(rows["plain"])])
                 for name in rows}
    # leaving points out can only take support away, never add it
    assert np.all(supported["segmented"] <= supported["plain"] + 1e-9)
    summary = json.loads((segmented / "summary.json").read_text())
    assert summary["segmentation"]["checkpoint"] == str(checkpoint)
    assert 0 <= summary["segmentation"]["others_share"] <= 1
