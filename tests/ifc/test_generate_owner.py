"""Generated buildings stay byte-reproducible even when the process configured IfcOpenShell's owner callbacks."""

from __future__ import annotations

import time

import pytest

from bimscan.cli.main import main


@pytest.mark.parametrize("schedule", [[], ["--schedule", "2024-03-04"]], ids=["building", "with a work schedule"])
def test_owner_history_callbacks_set_elsewhere_do_not_leak_a_timestamp_into_the_file(tmp_path, tiny_model, schedule):
    tiny_model("IFC2X3")  # sets ifcopenshell.api's owner callbacks, as a user's script might
    assert main(["make-building", str(tmp_path / "a.ifc"), "--seed", "11", "--storeys", "1", *schedule]) == 0
    time.sleep(1.1)  # an owner history, or the clock the api stamps a work plan with, would carry another second
    assert main(["make-building", str(tmp_path / "b.ifc"), "--seed", "11", "--storeys", "1", *schedule]) == 0
    assert (tmp_path / "a.ifc").read_bytes() == (tmp_path / "b.ifc").read_bytes()
