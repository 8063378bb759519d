"""stage.uv_sphere: the latitude-longitude sphere every test and script builds its scenes on."""

import numpy as np
import pytest

import stage


def test_vertices_on_the_sphere_normals_outward_and_area_converges():
    m = stage.uv_sphere(50.0, 32, 64, center=(1.0, 2.0, 3.0))
    v = np.asarray(m.vertices) - [1.0, 2.0, 3.0]
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 50.0, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(m.normals), v / 50.0, atol=1e-12)
    tri = np.asarray(m.vertices)[np.asarray(m.faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    # An inscribed polyhedron: its area is below 4 pi r^2 and within 1% of it at 32 x 64 (chord error ~ (pi/64)^2).
    assert 0.99 * 4 * np.pi * 50.0**2 < area.sum() < 4 * np.pi * 50.0**2
    assert np.all(area > 0)  # the degenerate pole triangles are dropped
    centroid = tri.mean(axis=1) - [1.0, 2.0, 3.0]
    assert np.all(np.sum(cross * centroid, axis=1) > 0)  # counter-clockwise seen from outside
    uv = np.asarray(m.uv)
    assert uv.min() >= 0 and uv.max() <= 1


def test_without_uv_and_bad_arguments():
    assert stage.uv_sphere(10.0, 4, 8, with_uv=False).uv is None
    with pytest.raises(ValueError, match="uv_sphere"):
        stage.uv_sphere(0.0, 4, 8)
