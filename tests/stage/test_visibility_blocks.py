"""stage.Occluder for a block of samples on a shared BVH (``bvh=``), its geometric normals computed when read,
and camera_visibility's projections padded to a few lengths: each the same answer as the whole at once."""

import numpy as np
import pytest

import stage
from stage._host import host_fields, host_subset
from stage._visibility import _OCCLUDER_BLOCK, _padded


def test_an_occluder_per_block_on_one_bvh_is_the_whole_ones():
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, 24)
    whole = stage.Occluder(mesh, surf)
    fields = host_fields(surf)
    for r in (slice(0, 50), slice(50, surf.num_samples)):
        part = stage.Occluder(mesh, host_subset(fields, surf.resolution, r), bvh=whole)
        assert part.intersector is whole.intersector
        for name in ("origin", "surface_origin", "geometric_normal", "normal"):
            np.testing.assert_array_equal(getattr(part, name), getattr(whole, name)[r], err_msg=name)
    ng = whole.geometric_normal
    np.testing.assert_allclose(np.linalg.norm(ng, axis=1), 1.0, rtol=1e-12)
    assert np.all(np.sum(ng * np.asarray(surf.normal, np.float64), axis=1) >= 0)  # on the shading normal's side
    # The origins left the triangle along it: surface_origin - position is a positive multiple of n_g.
    lift = whole.surface_origin - np.asarray(surf.position, np.float64)
    np.testing.assert_allclose(np.cross(lift, ng), 0.0, atol=1e-9)
    assert np.all(np.sum(lift * ng, axis=1) > 0)
    with pytest.raises(ValueError, match="faces"):
        stage.Occluder(stage.uv_sphere(50.0, 6, 12), bvh=whole)


def test_camera_visibility_of_any_candidates_is_the_whole_ones():
    mesh = stage.load_head()
    surf = stage.texel_samples(mesh, 24)
    v = np.asarray(mesh.vertices, np.float64)
    cam = stage.camera_ring(1, 1300.0, target=tuple(0.5 * (v.min(0) + v.max(0))), fov_deg=20.0, width=24,
                            height=20)[0]
    occ = stage.Occluder(mesh, surf)
    whole = stage.camera_visibility(mesh, surf, [cam], occluder=occ)[0]
    assert 0 < int(whole.sum()) < surf.num_samples
    rng = np.random.default_rng(1)
    for frac in (0.003, 0.3, 0.9):  # 1 to hundreds of candidates: padded to 2^10 samples for the projection
        cand = rng.uniform(0, 1, surf.num_samples) < frac
        got = stage.camera_visibility(mesh, surf, [cam], occluder=occ, candidates=cand)[0]
        np.testing.assert_array_equal(got, whole & cand)
    assert [_padded(n) for n in (1, 1024, 1025, 5000)] == [1024, 1024, 2048, 8192]
    assert _padded(_OCCLUDER_BLOCK) == _OCCLUDER_BLOCK and _padded(_OCCLUDER_BLOCK - 1) == _OCCLUDER_BLOCK
