"""Metadata from file names (--name-pattern) and a sidecar table keyed by file name (issue 23, item 7)."""
from __future__ import annotations

import pytest

from canopy_stereo.batch.naming import fields_from_name, read_sidecar, sidecar_row
from canopy_stereo.errors import CanopyStereoError


def test_fields_from_a_file_name():
    assert fields_from_name("P7_drought_2024-05-01.mcap", "{plant_id}_{treatment}_{date}") == {
        "plant_id": "P7", "treatment": "drought", "date": "2024-05-01"}
    assert fields_from_name("plot3-A12.mcap", "plot{plot}-{plant_id}") == {"plot": "3", "plant_id": "A12"}
    assert fields_from_name("x_12.mcap", r"(?P<kind>[a-z]+)_(?P<n>\d+)") == {"kind": "x", "n": "12"}


@pytest.mark.parametrize(("name", "pattern", "word"), [("P7-2024.mcap", "{plant_id}_{date}", "does not match"),
                                                       ("a.mcap", "plain", "names no field"),
                                                       ("a_b.mcap", "{x}_{x}", "twice")])
def test_bad_names_and_patterns_are_one_line_errors(name, pattern, word):
    with pytest.raises(CanopyStereoError, match=word) as exc:
        fields_from_name(name, pattern)
    assert "\n" not in str(exc.value)


def test_sidecar_table_keyed_by_file_name(tmp_path):
    table = tmp_path / "meta.csv"
    table.write_text("\ufeffgenotype,File,plot\njade,season/P7_drought.mcap,3\ncroton,C1_control,4\n")
    rows = read_sidecar(table)
    assert sidecar_row(rows, "/data/P7_drought.mcap") == {"genotype": "jade", "plot": "3"}
    assert sidecar_row(rows, "C1_control.mcap") == {"genotype": "croton", "plot": "4"}
    assert sidecar_row(rows, "other.mcap") == {}
    table.write_text("file,plot\na.mcap,1\na,2\n")
    with pytest.raises(CanopyStereoError, match="listed twice"):
        read_sidecar(table)
    table.write_text("file,plot\na.mcap\n")
    with pytest.raises(CanopyStereoError, match="line 2"):
        read_sidecar(table)


def test_the_rig_is_given_else_in_the_bag_else_beside_it(tmp_path):
    from pathlib import Path

    from canopy_stereo.batch.work import BatchOptions, resolve_rig
    from canopy_stereo.io.rig import load_rig

    repo = Path(__file__).resolve().parents[2]
    croton, plants = load_rig(repo / "config/croton_rig.yaml"), load_rig(repo / "config/plants_rig.yaml")
    bag = tmp_path / "b.mcap"
    with pytest.raises(CanopyStereoError, match="no rig.*rig.yaml beside"):
        resolve_rig(bag, None, BatchOptions())
    (tmp_path / "rig.yaml").write_text((repo / "config/plants_rig.yaml").read_text())
    rig, source = resolve_rig(bag, None, BatchOptions())
    assert source == str(tmp_path / "rig.yaml") and rig.image_size == plants.image_size
    assert resolve_rig(bag, croton, BatchOptions()) == (croton, "bag")  # the bag's own first
    assert resolve_rig(bag, croton, BatchOptions(rig=plants, rig_source="x.yaml")) == (plants, "x.yaml")
