"""Rig files (stage.save_rig / load_rig, rig_to_dict / rig_from_dict): the one
JSON schema for capture folders, map sets and ``relight --rig``, the forms
earlier versions wrote, and errors that name the file and the field."""

import json

import numpy as np
import pytest

import stage


@pytest.mark.parametrize("rig", [stage.light_stage_x(), stage.geodesic_dome(1), stage.fibonacci_sphere(20)],
                         ids=["lsx", "dome", "fibonacci"])
def test_round_trip(tmp_path, rig):
    path = stage.save_rig(tmp_path / "rig.json", rig)
    back = stage.load_rig(path)
    assert back.near_field == rig.near_field and back.num_lights == rig.num_lights
    for f in ("position", "intensity", "solid_angle"):
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(rig, f)))
    assert stage.rig_from_dict(json.loads(path.read_text())).num_lights == rig.num_lights


def test_directions_and_defaults():
    """A rig given by 'directions' (other tools' capture folders): lights 1 m out,
    distant by default, intensity 1, Voronoi solid angles."""
    d = np.asarray(stage.geodesic_dome(0).directions, np.float64) * 5.0
    rig = stage.rig_from_dict({"directions": d.tolist(), "distant": True})
    assert not rig.near_field
    np.testing.assert_allclose(np.linalg.norm(np.asarray(rig.position), axis=1), 1000.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rig.intensity), 1.0)
    np.testing.assert_allclose(np.asarray(rig.solid_angle).sum(), 4 * np.pi, rtol=1e-5)
    # positions alone: near field by default; a solid-angle table of the wrong length is ignored.
    rig = stage.rig_from_dict({"positions": (d * 100).tolist(), "intensities": [1.0] * 12, "solid_angles": [1.0]})
    assert rig.near_field and rig.intensity.shape == (12, 3)
    np.testing.assert_allclose(np.asarray(rig.solid_angle).sum(), 4 * np.pi, rtol=1e-5)


def test_errors_name_the_file_and_the_field(tmp_path):
    pos = (np.asarray(stage.geodesic_dome(0).position)).tolist()
    cases = [
        ([1, 2], r"r\.json: a rig must be a JSON object"),
        ({"intensities": [1.0]}, r"r\.json: rig needs field 'positions' or 'directions'"),
        ({"positions": [[1.0, 2.0]]}, r"r\.json: field 'positions' must be \[L, 3\]"),
        ({"positions": "here"}, r"r\.json: field 'positions' must be \[L, 3\]"),
        ({"directions": [[0.0, 0.0, 0.0]] + pos[1:]}, r"r\.json: field 'directions' has a zero vector \(row 0\)"),
        ({"positions": pos, "near_field": "yes"}, r"r\.json: field 'near_field' must be true or false"),
        ({"positions": pos, "intensities": [[-1.0, 1.0, 1.0]] * 12}, r"r\.json: bad rig \(light intensities"),
        ({"positions": pos, "solid_angles": [-1.0] * 12}, r"r\.json: field 'solid_angles' must be finite"),
    ]
    for doc, pattern in cases:
        (tmp_path / "r.json").write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=pattern):
            stage.load_rig(tmp_path / "r.json")
    (tmp_path / "r.json").write_text("{oops")
    with pytest.raises(ValueError, match=r"r\.json: not valid JSON"):
        stage.load_rig(tmp_path / "r.json")
    with pytest.raises(FileNotFoundError, match="none.json"):
        stage.load_rig(tmp_path / "none.json")
