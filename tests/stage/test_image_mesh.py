import numpy as np
import pytest

import stage

from ..scenes import merge, plane, uv_sphere


def test_check_mesh_reports_degenerate_faces(tmp_path):
    m = plane(size=10.0, n=2)
    faces = np.concatenate([m.faces, [[0, 1, 2], [0, 0, 3], [0, 1, 99]]])  # collinear, repeated, out of range
    bad = stage.Mesh(m.vertices, faces, m.normals, m.uv, "bad")
    rep = stage.check_mesh(bad)
    assert not rep.ok
    assert rep.degenerate_faces.tolist() == [8, 9]  # 0-1-2 are collinear (one grid row), 0-0-3 repeats
    assert rep.repeated_index_faces.tolist() == [9]
    assert rep.out_of_range_faces.tolist() == [10]
    assert "degenerate faces: 2" in rep.summary()
    assert stage.check_mesh(m).ok
    with pytest.raises(ValueError, match="no UV"):
        stage.check_mesh(uv_sphere(with_uv=False), require_uv=True)
    # load_mesh drops zero-area faces and says which.
    path = tmp_path / "tri.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    loaded = stage.load_mesh(path)
    assert len(loaded.faces) == 1 and loaded.dropped_faces.tolist() == [1]
    assert stage.check_mesh(loaded).dropped_on_load == 1


@pytest.fixture(scope="module")
def sphere():
    return uv_sphere(radius=50.0, n_lat=32, n_lon=64)


def test_image_samples_lie_on_the_visible_surface(sphere):
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=64, height=64)
    im = stage.image_samples(sphere, cam)
    p = np.asarray(im.position, np.float64)
    # On the sphere to the mesh's chord error: a cell spans pi/32 in latitude and longitude,
    # its centre sits ~2 R (1 - cos(pi / 64)) = 0.12 mm inside the sphere.
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), 50.0, atol=0.13)
    assert np.all(p[:, 2] > -1.0)  # only the front half is hit
    # Barycentrics reproduce the position.
    lam = np.asarray(im.barycentric, np.float64)
    tri = sphere.vertices[sphere.faces[np.asarray(im.face)]]
    np.testing.assert_allclose(np.sum(tri * lam[:, :, None], axis=1), p, atol=1e-3)
    # Pixel footprints tile the surface: the samples whose radial direction lies within
    # 50 degrees of +z cover the cap of area 2 pi R^2 (1 - cos 50); 2% for its pixel-stair boundary.
    zone = 2 * np.pi * 50.0**2 * (1 - np.cos(np.deg2rad(50)))
    orth = stage.orthographic((0.0, 0.0, 1000.0), extent_mm=120.0, width=64, height=64)
    for s in (im, stage.image_samples(sphere, orth)):
        q = np.asarray(s.position, np.float64)
        inside = q[:, 2] / np.linalg.norm(q, axis=1) > np.cos(np.deg2rad(50))
        np.testing.assert_allclose(float(np.sum(np.asarray(s.area, np.float64)[inside])), zone, rtol=2e-2)


def test_camera_behind_everything_is_refused(sphere):
    away = stage.look_at((0.0, 0.0, 1000.0), target=(0.0, 0.0, 2000.0))
    with pytest.raises(ValueError, match="sees no part of mesh 'sphere'"):
        stage.image_samples(sphere, away)


def test_packed_visibility_matches_the_bool_mask(sphere, tmp_path):
    s = stage.texel_samples(sphere, 16)
    rig = stage.geodesic_dome(1)
    vis = stage.light_visibility(sphere, s, rig)
    packed = stage.light_visibility(sphere, s, rig, packed=True)
    assert packed.shape == vis.shape and packed.nbytes == vis.shape[0] * ((vis.shape[1] + 7) // 8)
    np.testing.assert_array_equal(np.asarray(packed), vis)
    np.testing.assert_array_equal(packed.unpack(13, 29), vis[:, 13:29])
    packed.save(tmp_path / "vis.npz")
    np.testing.assert_array_equal(stage.PackedMask.load(tmp_path / "vis.npz").unpack(), vis)


def test_orthographic_camera_visibility():
    m = merge(plane(size=200.0, n=20, y=0.0), uv_sphere(radius=30.0, center=(0.0, 60.0, 0.0), with_uv=False))
    s = stage.texel_samples(m, 64)
    top = stage.orthographic((0.0, 500.0, 0.0), up=(0.0, 0.0, -1.0), extent_mm=300.0, width=128, height=128)
    cv = stage.camera_visibility(m, s, top)
    r = np.hypot(np.asarray(s.position)[:, 0], np.asarray(s.position)[:, 2])
    # Parallel projection: the sphere hides exactly the disc r < 30 (one texel of margin).
    assert not cv[0, r < 27.0].any()
    assert cv[0, r > 33.0].all()
