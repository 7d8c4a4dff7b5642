"""Datasets of sites: per-configuration stage and clutter, stage sweeps, stations per site state,
fingerprints that rebuild exactly the units a site change affects."""

from __future__ import annotations

from pathlib import Path

import pytest

from bimscan.dataset.layout import DatasetFolder
from bimscan.dataset.plan import generate_scenes, plan_build
from bimscan.dataset.spec import load_spec
from bimscan.errors import ConfigError

SPEC = """\
name = "site"
seed = 3
formats = ["npy"]
{top}
[[scenes]]
name = "office"
generate = {{ seed = 1, storeys = 1 }}

[[configs]]
name = "empty"
preset = "exp1"
head_deg_per_s = 360.0
{empty}
[[configs]]
name = "busy"
preset = "exp1"
head_deg_per_s = 360.0
{busy}
"""


def write_spec(folder: Path, *, top: str = "", empty: str = "", busy: str = 'clutter = { density = 0.2 }') -> Path:
    path = folder / "spec.toml"
    path.write_text(SPEC.format(top=top, empty=empty, busy=busy), encoding="utf-8")
    return path


def test_configurations_carry_their_stage_and_clutter_or_the_specs(tmp_path):
    spec = load_spec(write_spec(tmp_path, top='stage = "enclosed"\nclutter = { density = 0.1, kinds = ["site"] }',
                                busy='stage = { name = "structure", props_fraction = 0.5 }'))
    empty, busy = (spec.site(c) for c in spec.configs)
    assert empty.stage.name == "enclosed" and empty.clutter.density == 0.1 and empty.clutter.kinds == ("site",)
    assert busy.stage.name == "structure" and busy.stage.props_fraction == 0.5 and busy.clutter.density == 0.1
    recipe = spec.recipe(spec.scenes[0], spec.configs[1])
    assert recipe.site == busy and recipe.to_json()["site"]["stage"]["props_fraction"] == 0.5


def test_a_stages_sweep_makes_one_unit_per_scene_configuration_and_stage(tmp_path):
    sweep = 'stages = ["structure", { name = "enclosed", walls_missing_fraction = 0.2 }, "finished"]'
    spec = load_spec(write_spec(tmp_path, top=sweep))
    stages = ("structure", "enclosed", "finished")
    assert spec.unit_ids() == [f"office__{c}.{s}" for c in ("empty", "busy") for s in stages]
    enclosed = spec.site(spec.config("busy.enclosed"))
    assert enclosed.stage.walls_missing_fraction == 0.2 and enclosed.clutter.density == 0.2


@pytest.mark.parametrize("top, busy, message", [
    ('stages = ["structure"]\nstage = "enclosed"', "", "not both"),
    ('stages = ["structure"]', 'stage = "enclosed"', "sets its own 'stage'"),
    ('stages = ["structure", "structure"]', "", "more than once"),
    ("", 'clutter = { density = 0.2, kinds = ["piano"] }', r"\[\[configs\]\] #2 key 'clutter': unknown clutter kind 'piano'"),
    ("", 'clutter = { density = -0.2 }', (r"key 'clutter': clutter density must be a number in \[0, 2\] \(objects "
                                          r"per square metre of free floor, 0: none\), got -0.2")),
    ("", 'clutter = { denisty = 0.2 }', "unknown key"),
    ('stage = "roughcast"', "", "key 'stage': stage name takes 'structure', 'enclosed', 'finished', got 'roughcast'"),
])
def test_bad_site_settings_in_a_spec_are_refused_before_any_work(tmp_path, top, busy, message):
    with pytest.raises(ConfigError, match=message):
        load_spec(write_spec(tmp_path, top=top, busy=busy))


def plan(folder: Path, spec_path: Path):
    spec = load_spec(spec_path)
    dataset = DatasetFolder(folder)
    return plan_build(spec, dataset, generate_scenes(spec, dataset))


def test_each_site_state_of_a_scene_gets_its_own_stations_and_a_density_change_touches_only_its_units(tmp_path):
    (tmp_path / "out" / "scenes").mkdir(parents=True)
    first = plan(tmp_path / "out", write_spec(tmp_path, empty='clutter = { density = 0.2 }'))
    # two configurations, one site state: one scene job
    assert [j.site_tag for j in first.scene_jobs] == [first.unit_jobs["office__busy"].site_tag]
    second = plan(tmp_path / "out", write_spec(tmp_path))
    assert len(second.scene_jobs) == 2 and len({j.stations_file for j in second.scene_jobs}) == 2
    assert second.unit_jobs["office__empty"].site_tag == ""
    busy_scene_job = next(j for j in second.scene_jobs if j.site_tag == second.unit_jobs["office__busy"].site_tag)
    assert second.unit_jobs["office__busy"].site_key == busy_scene_job.stations_key  # the unit reads its dressing
    assert busy_scene_job.site_file.endswith(".site.npz")
    assert second.unit_jobs["office__busy"].fingerprint == first.unit_jobs["office__busy"].fingerprint
    assert second.unit_jobs["office__empty"].fingerprint != first.unit_jobs["office__empty"].fingerprint
    third = plan(tmp_path / "out", write_spec(tmp_path, busy='clutter = { density = 0.3 }'))
    assert third.unit_jobs["office__empty"].fingerprint == second.unit_jobs["office__empty"].fingerprint
    assert third.unit_jobs["office__busy"].fingerprint != second.unit_jobs["office__busy"].fingerprint
    assert third.unit_jobs["office__busy"].site_tag != second.unit_jobs["office__busy"].site_tag


@pytest.mark.slow
def test_a_site_dataset_records_what_was_placed_and_rebuilds_only_what_a_change_affects(tmp_path, session_env):
    from bimscan.dataset.build import build_dataset

    out = tmp_path / "out"
    report = build_dataset(load_spec(write_spec(tmp_path)), out, workers=1, executor="serial", progress=False)
    assert report.ok and report.built == 2
    folder = DatasetFolder(out)
    empty, busy = folder.read_unit("office__empty"), folder.read_unit("office__busy")
    assert empty.site == {}
    assert sum(busy.site["placed"].values()) >= 10 and busy.site["rooms"] >= 5
    assert busy.class_histogram["Others"] > empty.class_histogram["Others"]
    stations_files = sorted(p.name for p in folder.scenes_dir.glob("*.stations.json"))
    assert len(stations_files) == 2 and "office.stations.json" in stations_files
    (site_file,) = folder.scenes_dir.glob("office.*.site.npz")  # dressed once, read by the unit
    assert site_file.name.replace(".site.npz", ".stations.json") in stations_files
    assert sorted(e.status for e in folder.read_manifest().units) == ["done", "done"]
    before = (folder.unit_dir("office__empty") / "unit.json").read_bytes()

    again = build_dataset(load_spec(write_spec(tmp_path, busy='clutter = { density = 0.1 }')), out, workers=1,
                          executor="serial", progress=False)
    assert again.ok and again.built == 1 and again.reused == 1
    assert (folder.unit_dir("office__empty") / "unit.json").read_bytes() == before
    assert folder.read_unit("office__busy").inputs["recipe"]["site"]["clutter"]["density"] == 0.1


def test_a_stored_dressed_scene_reads_back_as_the_scene_dressed_again(tmp_path, box_room_ifc):
    from bimscan.dataset.layout import read_site_scene, write_site_scene
    from bimscan.pipeline import build_site, load_scene
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.site import ClutterSettings, SiteModel

    scene = load_scene(box_room_ifc)
    recipe = ScanRecipe(seed=4, site=SiteModel(clutter=ClutterSettings(density=0.3)))
    dressed = build_site(scene, recipe)
    write_site_scene(tmp_path / "a.site.npz", dressed, "key-1")
    write_site_scene(tmp_path / "b.site.npz", build_site(scene, recipe), "key-1")
    assert (tmp_path / "a.site.npz").read_bytes() == (tmp_path / "b.site.npz").read_bytes()  # same scene, same bytes
    back = read_site_scene(tmp_path / "a.site.npz", scene, "key-1")
    assert back.mesh.vertices.tobytes() == dressed.mesh.vertices.tobytes()
    assert back.mesh.face_transparency.tobytes() == dressed.mesh.face_transparency.tobytes()
    assert back.components.rows() == dressed.components.rows() and back.site == dressed.site
    assert dict(back.components.class_ancestry) == dict(dressed.components.class_ancestry)
    assert read_site_scene(tmp_path / "a.site.npz", scene, "key-2") is None  # dressed from something else
    (tmp_path / "a.site.npz").write_bytes(b"garbage")
    assert read_site_scene(tmp_path / "a.site.npz", scene, "key-1") is None
