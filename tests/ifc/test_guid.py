"""IFC GlobalIds: what is one, and the ones bimscan derives are."""

from __future__ import annotations

import pytest

from bimscan.ifc.guid import derived_global_id, is_global_id


@pytest.mark.parametrize(("text", "valid"), [
    ("2O2Fr$t4X7Zf8NOew3FLOH", True),
    ("0000000000000000000000", True),
    ("4O2Fr$t4X7Zf8NOew3FLOH", False),  # 128 bits leave the first character 0-3
    ("2O2Fr$t4X7Zf8NOew3FLO", False),  # 21 characters
    ("2O2Fr-t4X7Zf8NOew3FLOH", False),  # '-' is not in IFC's base 64
    ("6F9619FF-8B86-D011-B42D-00CF4FC964FF", False),  # a GUID in another form
    (None, False),  # '$': unset
])
def test_an_ifc_global_id_is_22_characters_of_ifc_base_64_starting_0_to_3(text, valid):
    assert is_global_id(text) is valid


def test_derived_global_ids_are_global_ids():
    assert all(is_global_id(derived_global_id("file", i)) for i in range(200))
