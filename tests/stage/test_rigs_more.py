import numpy as np
import pytest

import stage


def test_fibonacci_sphere_is_nearly_uniform():
    rig = stage.fibonacci_sphere(200)
    assert rig.num_lights == 200 and not rig.near_field
    omega = np.asarray(rig.solid_angle, np.float64)
    np.testing.assert_allclose(omega.sum(), 4 * np.pi, rtol=1e-5)
    # Golden-angle spiral: every Voronoi cell within 15% of the mean 4 pi / n (Gonzalez 2010).
    assert np.abs(omega / (4 * np.pi / 200) - 1).max() < 0.15
    # The directions' mean is ~0 (no hemisphere bias): |mean| < 1 / n.
    assert np.linalg.norm(np.asarray(rig.directions, np.float64).mean(0)) < 1.0 / 200
    up = stage.fibonacci_sphere(100, hemisphere=True, near_field=True, radius_mm=500.0)
    assert np.all(np.asarray(up.directions)[:, 1] > 0)
    np.testing.assert_allclose(np.asarray(up.center_irradiance), 1.0, rtol=1e-5)


def test_directional_rig_from_diligent_files(tmp_path):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(96, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.5  # DiLiGenT lights face the object: z > 0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    inten = rng.uniform(0.5, 2.0, size=(96, 3))
    np.savetxt(tmp_path / "light_directions.txt", d)
    np.savetxt(tmp_path / "light_intensities.txt", inten)
    rig = stage.directional_rig(tmp_path / "light_directions.txt", tmp_path / "light_intensities.txt")
    assert rig.num_lights == 96 and not rig.near_field
    np.testing.assert_allclose(np.asarray(rig.directions), d, atol=1e-6)
    np.testing.assert_allclose(np.asarray(rig.intensity), inten, rtol=1e-6)
    # Bad files name the file and the problem.
    np.savetxt(tmp_path / "short.txt", inten[:10])
    with pytest.raises(ValueError, match="short.txt.*10 intensity rows for 96"):
        stage.directional_rig(tmp_path / "light_directions.txt", tmp_path / "short.txt")
    np.savetxt(tmp_path / "long.txt", 2 * d)
    with pytest.raises(ValueError, match="long.txt.*line 1 has length 2"):
        stage.directional_rig(tmp_path / "long.txt")
    (tmp_path / "junk.txt").write_text("1 2\n3 4\n")
    with pytest.raises(ValueError, match="junk.txt.*rows of 3"):
        stage.directional_rig(tmp_path / "junk.txt")
    np.savetxt(tmp_path / "dup.txt", np.concatenate([d[:5], d[:1]]))
    with pytest.raises(ValueError, match="dup.txt.*coincident"):
        stage.directional_rig(tmp_path / "dup.txt")


def test_gonioreflectometer_arcs():
    g = stage.gonioreflectometer([0, 15, 30, 45, 60], [10, 40], phi_o_deg=[0, 90, 180])
    assert g.rig.num_lights == 5 and len(g.cameras) == 6
    p = np.asarray(g.rig.position, np.float64)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 1000.0, rtol=1e-6)
    # Light polar angle from the sample normal (+y) is theta_i; all in the phi_i = 180 plane (x <= 0, z = 0).
    np.testing.assert_allclose(np.degrees(np.arccos(p[:, 1] / 1000)), [0, 15, 30, 45, 60], atol=1e-4)
    np.testing.assert_allclose(p[:, 2], 0, atol=1e-3)
    # Lights on one great circle: lune solid angles, still a partition of the sphere.
    np.testing.assert_allclose(np.sum(np.asarray(g.rig.solid_angle, np.float64)), 4 * np.pi, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(g.rig.solid_angle)[1:4], 2 * np.deg2rad(15), rtol=1e-5)
    # Irradiance 1 at the sample centre at normal incidence.
    np.testing.assert_allclose(np.asarray(g.rig.center_irradiance), 1.0, rtol=1e-5)
    for cam, to in zip(g.cameras, np.asarray(g.theta_o), strict=True):
        c = np.asarray(cam.center, np.float64)
        np.testing.assert_allclose(np.linalg.norm(c), 600.0, rtol=1e-5)
        np.testing.assert_allclose(np.arccos(c[1] / 600.0), to, atol=1e-5)
        pix, _ = cam.project(np.zeros((1, 3), np.float32))  # the sample centre is the image centre
        np.testing.assert_allclose(np.asarray(pix)[0], [16, 16], atol=1e-3)
    with pytest.raises(ValueError, match="theta_i_deg"):
        stage.gonioreflectometer([0, 95], [10])


def test_per_light_rgb_calibration():
    rig = stage.geodesic_dome(1)
    gains = np.random.default_rng(2).uniform(0.8, 1.2, size=(rig.num_lights, 3))
    cal = stage.calibrate(rig, gains)
    np.testing.assert_allclose(np.asarray(cal.intensity), np.asarray(rig.intensity) * gains, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(cal.solid_angle), np.asarray(rig.solid_angle))
    same = stage.make_rig(np.asarray(rig.position), 1.0, near_field=False, calibration=gains)
    np.testing.assert_allclose(np.asarray(same.intensity), np.asarray(cal.intensity), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(stage.calibrate(rig, [1.0, 0.5, 2.0]).intensity)[7], [1.0, 0.5, 2.0])
    with pytest.raises(ValueError, match="calibration"):
        stage.calibrate(rig, np.ones((5, 3)))
    with pytest.raises(ValueError, match="non-negative"):
        stage.calibrate(rig, [1.0, -1.0, 1.0])


def test_light_stage_x_triangulation():
    pol = stage.light_stage_x("polarized")
    d = np.asarray(pol.directions, np.float64)
    for source, n_faces in (("table", 168), ("hull", 166)):
        f = stage.light_stage_x_faces(source)
        assert f.shape == (n_faces, 3) and f.min() == 0 and f.max() == 84
        assert len(np.unique(np.sort(f, axis=1), axis=0)) == n_faces  # no repeated triangle
        v = d[f]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        assert np.all(np.sum(n * v.mean(1), axis=1) > 0)  # wound outward
    # The convex hull is a closed triangulation of the sphere: V - E + F = 2, every edge in 2 faces.
    f = stage.light_stage_x_faces("hull")
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2) and 85 - len(counts) + len(f) == 2
    # The table shares all but 10 faces with the hull; the rest is the fan around polarized
    # light 78 (raw row 322), which the table built at the duplicated row-197 position.
    table = set(map(tuple, np.sort(stage.light_stage_x_faces("table"), 1)))
    hull = set(map(tuple, np.sort(f, 1)))
    assert len(table & hull) == 156


def test_lights_on_a_great_circle_get_lunes():
    ang = np.deg2rad([0, 90, 180, 270])
    rig = stage.make_rig(np.stack([np.cos(ang), np.zeros(4), np.sin(ang)], 1), near_field=False)
    np.testing.assert_allclose(np.asarray(rig.solid_angle), np.pi, rtol=1e-6)
