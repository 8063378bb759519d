import numpy as np
import pytest

import stage

from ..scenes import plane, uv_sphere


def test_texel_areas_sum_to_mesh_area():
    m = uv_sphere(radius=50.0)
    s = stage.texel_samples(m, 256)
    # Texel centres sample the UV atlas; the area sum converges to the mesh
    # area as resolution grows (1% at 256^2 for this atlas).
    np.testing.assert_allclose(float(np.sum(np.asarray(s.area, np.float64))), m.trimesh().area, rtol=1e-2)


def test_shading_frame_is_orthonormal_and_right_handed():
    s = stage.texel_samples(uv_sphere(), 64)
    n, t, b = (np.asarray(x, np.float64) for x in (s.normal, s.tangent, s.bitangent))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(np.sum(n * t, 1), 0, atol=1e-5)
    np.testing.assert_allclose(np.cross(t, b), n, atol=1e-5)
    # Sphere: the interpolated normal is the radial direction (to the chord error of the mesh).
    p = np.asarray(s.position, np.float64)
    np.testing.assert_allclose(np.sum(n * p / np.linalg.norm(p, axis=1, keepdims=True), 1), 1, atol=2e-3)


def test_plane_texels_land_on_their_uv():
    m = plane(size=100.0, n=10)
    s = stage.texel_samples(m, 32)
    assert s.num_samples == 32 * 32  # the plane fills its whole atlas
    uv = np.asarray(s.uv)
    p = np.asarray(s.position)
    np.testing.assert_allclose(p[:, 0], uv[:, 0] * 100 - 50, atol=1e-3)
    np.testing.assert_allclose(p[:, 2], (1 - uv[:, 1]) * 100 - 50, atol=1e-3)
    tex = s.to_texture(np.asarray(s.uv)[:, 0])
    # Column j of the texture holds u = (j + 0.5) / 32.
    np.testing.assert_allclose(tex[5], (np.arange(32) + 0.5) / 32, atol=1e-5)


def test_mesh_without_uvs_is_refused(tmp_path):
    with pytest.raises(ValueError, match="no UV"):
        stage.texel_samples(uv_sphere(with_uv=False), 16)
    path = tmp_path / "nouv.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="no UV"):
        stage.load_mesh(path, require_uv=True)
    m = stage.load_mesh(path)  # fine without the requirement; normals computed
    np.testing.assert_allclose(np.abs(m.normals[:, 2]), 1.0)


def test_missing_and_corrupt_mesh_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        stage.load_mesh(tmp_path / "absent.glb")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a mesh at all")
    with pytest.raises(ValueError, match="bad.glb"):
        stage.load_mesh(bad)


def test_bundled_head(shared_data):
    head = stage.load_head()
    ref = stage.load_mesh(shared_data / "meshes" / "lee_perry_smith_head.glb")
    assert head.faces.shape == ref.faces.shape == (17684, 3)
    s = stage.texel_samples(head, 128)
    # The atlas covers ~92% of UV space.
    assert 0.8 * 128 * 128 < s.num_samples < 128 * 128
    # The face looks toward +z (the main camera): the nose tip is the most forward point.
    assert np.asarray(s.normal)[np.argmax(np.asarray(s.position)[:, 2]), 2] > 0.5


def test_batched_texel_samples_equal_one_batch(monkeypatch):
    """Memory is bounded by the candidate and sample batches, not the grid:
    tiny batches (a batch boundary inside triangles and between samples) give
    the same surface, field by field, bit for bit."""
    from stage import _surface

    mesh = uv_sphere(radius=10.0, n_lat=12, n_lon=24)
    whole = stage.texel_samples(mesh, 48)
    monkeypatch.setattr(_surface, "_CANDIDATE_BATCH", 97)
    monkeypatch.setattr(_surface, "_SAMPLE_BATCH", 61)
    small = stage.texel_samples(mesh, 48)
    assert small.num_samples == whole.num_samples > 500
    for name in ("position", "normal", "tangent", "bitangent", "uv", "area", "texel_index", "face", "barycentric"):
        np.testing.assert_array_equal(np.asarray(getattr(small, name)), np.asarray(getattr(whole, name)), err_msg=name)
