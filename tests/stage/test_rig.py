import numpy as np
import pytest

import stage


@pytest.mark.parametrize("s", [0, 1, 2, 3])
def test_geodesic_dome_counts_and_solid_angles(s):
    rig = stage.geodesic_dome(s)
    assert rig.num_lights == 10 * 4**s + 2
    # Voronoi cells partition the sphere: closed form 4 pi (float32 storage).
    np.testing.assert_allclose(float(np.sum(np.asarray(rig.solid_angle, np.float64))), 4 * np.pi, rtol=1e-5)
    d = np.asarray(rig.directions)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-6)


def test_light_stage_x_table():
    rig = stage.light_stage_x()
    assert rig.num_lights == 346 and rig.near_field
    r = np.linalg.norm(np.asarray(rig.position), axis=1)
    assert 1319.0 < r.min() and r.max() < 1329.0  # radius ~132 cm (data README)
    d = np.asarray(rig.directions, np.float64)
    g = d @ d.T
    np.fill_diagonal(g, -1)
    nn = np.degrees(np.arccos(np.clip(g.max(1), -1, 1)))
    # Every light distinct: the restored row 322 removes the duplicate of row 197.
    assert nn.min() > 3.0, nn.min()
    np.testing.assert_allclose(np.sum(np.asarray(rig.solid_angle, np.float64)), 4 * np.pi, rtol=1e-5)
    assert stage.light_stage_x("polarized").num_lights == 85
    assert stage.light_stage_x("unpolarized").num_lights == 201
    # Default intensity: irradiance ~1 at the centre from every light (radius spread < 1%).
    np.testing.assert_allclose(np.asarray(rig.center_irradiance), 1.0, rtol=1e-2)


def test_inverse_square_falloff():
    rig = stage.make_rig(np.eye(3).tolist() + (-np.eye(3)).tolist(), intensity=4.0, near_field=True)
    # Point at (0.5, 0, 0): light 0 at (1, 0, 0) is 0.5 away -> E = 4 / 0.25 = 16.
    wi, e = rig.incident(np.array([[0.5, 0.0, 0.0]], np.float32))
    np.testing.assert_allclose(np.asarray(e)[0, 0], 16.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(wi)[0, 0], [1, 0, 0], atol=1e-7)
    # Light 3 at (-1, 0, 0) is 1.5 away.
    np.testing.assert_allclose(np.asarray(e)[3, 0], 4.0 / 2.25, rtol=1e-6)


def test_distant_lights_are_position_independent():
    rig = stage.geodesic_dome(1, irradiance=2.0)
    pts = np.array([[0.0, 0, 0], [100.0, -50, 3]], np.float32)
    wi, e = rig.incident(pts)
    np.testing.assert_allclose(np.asarray(wi)[:, 0], np.asarray(wi)[:, 1])
    np.testing.assert_allclose(np.asarray(e), 2.0)


@pytest.mark.parametrize(
    "positions, message",
    [
        (np.zeros((0, 3)), "at least one light"),
        (np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0, -1.0, 0]]), "coincident"),
        (np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]), "rig centre"),
        (np.ones((4, 2)), r"\[L, 3\]"),
    ],
)
def test_bad_rigs_raise(positions, message):
    with pytest.raises(ValueError, match=message):
        stage.make_rig(positions)
