"""Rig files as stages ship them: a list of per-light records (issue 28, item 4). The same lights written as
records and as the stage schema's arrays give the same rig; units and up axis must be stated; errors name the
file, the light and the field."""

import json

import numpy as np
import pytest

import stage


def _lights(n=6, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * 1500.0, rng.uniform(0.5, 2.0, (n, 3))  # mm, RGB intensity


def _write(path, doc):
    path.write_text(json.dumps(doc))
    return path


def test_records_equal_the_arrays(tmp_path):
    pos, inten = _lights()
    gains = np.linspace(0.9, 1.1, 6)
    recs = [{"id": f"L{i:02d}", "position": (p / 10).tolist(), "intensity": c.tolist(), "gain": float(g)}
            for i, (p, c, g) in enumerate(zip(pos, inten, gains, strict=True))]
    rig = stage.load_rig_file(_write(tmp_path / "r.json", {"units": "cm", "up": "+y", "lights": recs}))
    ref = stage.load_rig_file(_write(tmp_path / "a.json", {
        "units": "mm", "positions": pos.tolist(), "intensities": inten.tolist(),
        "calibration": np.repeat(gains[:, None], 3, 1).tolist()}))
    np.testing.assert_allclose(np.asarray(rig.position), np.asarray(ref.position), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rig.intensity), np.asarray(ref.intensity), rtol=1e-6)
    # The gains multiply the intensities (stage.calibrate): light 5 is 1.1 x its stated intensity.
    np.testing.assert_allclose(np.asarray(rig.intensity)[5], 1.1 * inten[5], rtol=1e-6)
    assert rig.near_field


def test_a_bare_list_with_the_units_and_up_given_by_the_caller(tmp_path):
    """A bare list records neither: the caller states both; an up of -z turns the file's -z to the stage's +y."""
    pos, _ = _lights()
    path = _write(tmp_path / "r.json", [{"position": p.tolist()} for p in pos / 1000.0])
    rig = stage.load_rig_file(path, units="m", up="-z")
    want = pos @ stage.up_rotation("-z").T
    np.testing.assert_allclose(np.asarray(rig.position), want, rtol=1e-5, atol=1e-3)
    # No intensity given: every light delivers irradiance 1 at the centre, as for a position table.
    r2 = np.sum(np.asarray(rig.position, np.float64) ** 2, 1)
    np.testing.assert_allclose(np.asarray(rig.intensity)[:, 0] / r2, np.mean(r2) / r2, rtol=1e-5)


def test_direction_records_are_a_distant_rig(tmp_path):
    pos, _ = _lights()
    d = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    rig = stage.load_rig_file(_write(tmp_path / "r.json", {"up": "+y", "lights": [{"direction": v.tolist()}
                                                                                  for v in d]}))
    assert not rig.near_field
    got = np.asarray(rig.position, np.float64)
    np.testing.assert_allclose(got / np.linalg.norm(got, axis=1, keepdims=True), d, atol=1e-6)


@pytest.mark.parametrize(("doc", "message"), [
    ({"up": "+y", "lights": [{"position": [0, 0, 1500]}]}, r"light records carry no unit; state it"),
    ({"units": "mm", "lights": [{"position": [0, 0, 1500]}]}, r"light records do not say which axis is up"),
    ({"units": "mm", "up": "+y", "lights": []}, r"field 'lights' must be a non-empty list"),
    ({"units": "mm", "up": "+y", "lights": [{"position": [0, 0, 1]}, {"direction": [0, 0, 1]}]},
     r"light 1 has no field 'position'"),
    ({"units": "mm", "up": "+y", "lights": [{"position": [0, 0, 1500], "intensity": [1, 2]}]},
     r"light 0: field 'intensity' must be a number or \[r, g, b\]"),
    ({"units": "mm", "up": "+y", "lights": ["L0"]}, r"light 0 must be an object"),
    ({"units": "in", "up": "+y", "lights": [{"position": [0, 0, 1500]}]}, r"field 'units' must be one of"),
])
def test_errors_name_the_file_the_light_and_the_field(tmp_path, doc, message):
    with pytest.raises(ValueError, match=r"r\.json: " + message):
        stage.load_rig_file(_write(tmp_path / "r.json", doc))


def test_subsets_of_a_record_file(tmp_path):
    pos, _ = _lights()
    path = _write(tmp_path / "r.json", {"units": "mm", "up": "+y", "subsets": {"front": [0, 2, 3, 5]},
                                        "lights": [{"position": p.tolist()} for p in pos]})
    assert list(stage.rig_file_subsets(path)["front"]) == [0, 2, 3, 5]
    assert stage.load_rig_file(path, subset="front").num_lights == 4
