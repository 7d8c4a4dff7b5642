"""Config as data: the built-in devices and settings, and the one way a user names one or passes a file."""

from __future__ import annotations

import shutil
from importlib import resources
from pathlib import Path

import pytest

from bimscan.errors import ConfigError
from bimscan.scan.device import PRESETS, SCANNER_TABLES, SCANNERS, load_scanner, load_settings
from bimscan.scan.lidars import MOBILE_LIDARS, load_lidar
from bimscan.scan.multibeam import LIDARS
from bimscan.scan.risley import RISLEY_SCANNERS
from bimscan.survey.platform import PLATFORM_NAMES, PLATFORMS, load_platform
from bimscan.toml_files import load_named

SCANNER_FOLDER = resources.files("bimscan.scan") / "scanners"


def _copy(name: str, folder: Path) -> Path:
    with resources.as_file(SCANNER_FOLDER / f"{name}.toml") as source:
        return Path(shutil.copy(source, folder / f"my_{name}.toml"))


# (loader, registry, the message's kind and the names it lists, a file of that kind's keys)
KINDS = {
    "scanner": (load_scanner, SCANNERS, "scanner 'nope' is neither a file nor a known scanner (riegl_vz400); pass a "
                                        "scanner TOML file", lambda folder: _copy("riegl_vz400", folder)),
    "lidar": (load_lidar, MOBILE_LIDARS, "lidar 'nope' is neither a file nor a known lidar (hesai_xt32, velodyne_vlp16, "
                                         "dji_zenmuse_l2, dji_zenmuse_l2_repetitive, livox_avia, livox_mid360, "
                                         "livox_mid40, livox_mid70); pass a scanner TOML file with kind = \"multibeam\" or \"risley\"",
              lambda folder: _copy("velodyne_vlp16", folder)),
    "platform": (load_platform, PLATFORMS, "platform 'nope' is neither a file nor a known platform (tripod, handheld, "
                                           "backpack, drone); pass a platform TOML file",
                 lambda folder: _write(folder / "pole.toml", "walking_speed_m_s = 0.8\n[[mounts]]\nheight_m = 2.5\n")),
    "preset": (load_settings, PRESETS, "preset 'nope' is neither a file nor a known preset (exp1, exp2, exp3, exp4, "
                                       "exp5, exp6); pass a settings TOML file",
               lambda folder: _write(folder / "s.toml", "pulse_freq_hz = 1e5\nscan_freq_hz = 100\nhead_deg_per_s = 20\n")),
}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_of_device_file_is_given_by_a_built_in_name_or_a_file_the_same_way(kind, tmp_path):
    # four loaders each had their own "name or file" code and words for it (issue 50): one function now
    load, registry, refusal, make_file = KINDS[kind]
    for name, entry in registry.items():
        assert load(name) is entry
    user_file = make_file(tmp_path)
    assert type(load(user_file)) is type(next(iter(registry.values())))
    assert type(load(str(user_file))) is type(next(iter(registry.values())))
    with pytest.raises(ConfigError) as caught:
        load("nope")
    assert str(caught.value).startswith(refusal)


def test_every_built_in_scanner_file_is_read_once_into_exactly_one_registry():
    files = sorted(p.name.removesuffix(".toml") for p in SCANNER_FOLDER.iterdir() if p.name.endswith(".toml"))
    assert sorted(SCANNER_TABLES) == files  # the folder, read once (the two registries read it twice)
    registries = (SCANNERS, LIDARS, RISLEY_SCANNERS)
    assert sum(len(r) for r in registries) == len(files) and sorted(name for r in registries for name in r) == files
    assert PLATFORM_NAMES == ("tripod", *PLATFORMS)


def test_a_device_file_of_the_other_kind_is_refused_saying_where_it_belongs(tmp_path):
    with pytest.raises(ConfigError, match="a multi-beam lidar for mobile scanning"):
        load_scanner(_copy("velodyne_vlp16", tmp_path))
    with pytest.raises(ConfigError, match="scanner 'velodyne_vlp16' is a multi-beam lidar"):
        load_scanner("velodyne_vlp16")
    with pytest.raises(ConfigError, match="describes a rotating-mirror TLS"):
        load_lidar(_copy("riegl_vz400", tmp_path))


def test_load_named_reads_a_file_with_its_reader_and_lists_the_names_it_was_given(tmp_path):
    registry = {"a": 1, "b": 2}
    path = _write(tmp_path / "c.toml", "value = 3\n")
    assert load_named("b", registry, kind="thing", read=lambda table, where: 0) == 2
    assert load_named(path, registry, kind="thing", read=lambda table, where: (table["value"], where)) == (3, path)
    with pytest.raises(ConfigError, match=r"^thing 'x' is neither a file nor a known thing \(z, a, b\); pass a file "
                                          r"of things$"):
        load_named("x", registry, kind="thing", read=lambda table, where: 0, names=("z", *registry),
                   file="a file of things")
