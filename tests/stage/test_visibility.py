import numpy as np
import pytest

import stage

from ..scenes import merge, plane, uv_sphere


def test_sphere_casts_its_shadow_where_geometry_says():
    # A sphere of radius 30 centred 60 above a plane, lit from straight above by a distant light.
    m = merge(plane(size=200.0, n=20, y=0.0), uv_sphere(radius=30.0, center=(0.0, 60.0, 0.0), with_uv=False))
    s = stage.texel_samples(m, 64)
    rig = stage.make_rig(np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, -1, -1]]), near_field=False)
    vis = stage.light_visibility(m, s, rig)
    p = np.asarray(s.position)
    r = np.hypot(p[:, 0], p[:, 2])
    # Orthographic shadow of the sphere: the disc r < 30 (margin of one texel plus the mesh's chord error).
    assert not vis[r < 28.0, 0].any()
    assert vis[r > 32.0, 0].all()
    # Light 3 is below the plane: never visible.
    assert not vis[:, 3].any()


def test_point_light_shadow_is_a_perspective_projection():
    m = merge(plane(size=400.0, n=20, y=0.0), uv_sphere(radius=20.0, center=(0.0, 100.0, 0.0), with_uv=False))
    s = stage.texel_samples(m, 128)
    light_h = 200.0
    rig = stage.make_rig(np.array([[0.0, light_h, 0], [1, 0, 0], [0, 0, 1], [-1, -1, -1]]), near_field=True)
    vis = stage.light_visibility(m, s, rig)
    r = np.hypot(np.asarray(s.position)[:, 0], np.asarray(s.position)[:, 2])
    # Cone from the light tangent to the sphere: half-angle asin(20/100); radius on the plane = 200 tan(asin(0.2)).
    r_shadow = light_h * np.tan(np.arcsin(20.0 / 100.0))
    assert not vis[r < r_shadow - 3.0, 0].any()
    assert vis[r > r_shadow + 3.0, 0].all()


def test_camera_visibility_hides_the_back_and_the_occluded():
    m = merge(plane(size=200.0, n=20, y=0.0), uv_sphere(radius=30.0, center=(0.0, 60.0, 0.0), with_uv=False))
    s = stage.texel_samples(m, 64)
    top = stage.look_at((0.0, 1000.0, 0.0), up=(0.0, 0.0, -1.0), fov_deg=20, width=256, height=256)
    below = stage.look_at((0.0, -1000.0, 0.0), up=(0.0, 0.0, -1.0), fov_deg=20, width=256, height=256)
    cv = stage.camera_visibility(m, s, [top, below])
    r = np.hypot(np.asarray(s.position)[:, 0], np.asarray(s.position)[:, 2])
    # From above, the sphere hides a disc of radius ~30 (perspective from 1 m: slightly less than 30/(1-0.09)).
    assert not cv[0, r < 28.0].any()
    inside_view = r < 80.0
    assert cv[0, (r > 36.0) & inside_view].all()
    # From below, the plane faces away: nothing is seen.
    assert not cv[1].any()
    # A shared occluder and a candidate subset give the same answer on the candidates, False elsewhere.
    occ = stage.Occluder(m, s)
    cand = np.asarray(s.position)[:, 0] > 0
    sub = stage.camera_visibility(m, s, [top, below], occluder=occ, candidates=cand)
    np.testing.assert_array_equal(sub, cv & cand[None])
    with pytest.raises(ValueError, match="occluder was built for"):
        stage.camera_visibility(m, s.subset(np.arange(10)), [top], occluder=occ)
    with pytest.raises(ValueError, match="candidates"):
        stage.camera_visibility(m, s, [top], candidates=np.ones(3, bool))


def test_occluder_is_the_ray_caster_of_light_visibility():
    """stage.Occluder.visible along the lights' directions (distant) or with the
    distances to them (near field) is light_visibility; inactive pairs and
    directions below the tangent plane are False and cast no ray."""
    m = merge(plane(size=200.0, n=20, y=0.0), uv_sphere(radius=30.0, center=(0.0, 60.0, 0.0), with_uv=False))
    s = stage.texel_samples(m, 32)
    occ = stage.Occluder(m, s)
    idx = np.arange(s.num_samples)
    dirs = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, 1], [-1, -1, -1]]) / np.array([1, 1, 1, np.sqrt(3)])[:, None]
    far = stage.make_rig(dirs, near_field=False)
    vis = occ.visible(idx, np.broadcast_to(dirs[None], (len(idx), 4, 3)))
    done = []
    np.testing.assert_array_equal(vis, stage.light_visibility(m, s, far, chunk=400, progress=lambda *a: done.append(a)))
    # stage.Progress: (sample, light) pairs done, from 0 to all of them, block by block (100 samples x 4 lights).
    P4 = 4 * s.num_samples
    assert done[0] == ("light visibility", 0, P4) and done[-1] == ("light visibility", P4, P4) and len(done) > 3
    near = stage.make_rig(np.array([[0.0, 200, 0], [150, 10, 0], [0, 10, 150], [-1, -1, -1]]), near_field=True)
    to = np.asarray(near.position, np.float64)[None] - occ.origin[:, None]
    dist = np.linalg.norm(to, axis=-1)
    np.testing.assert_array_equal(occ.visible(idx, to / dist[..., None], distance=dist),
                                  stage.light_visibility(m, s, near))
    active = np.zeros((len(idx), 4), bool)
    active[::2, 0] = True
    v = occ.visible(idx, np.broadcast_to(dirs[None], (len(idx), 4, 3)), active=active)
    np.testing.assert_array_equal(v, vis & active)
    # A segment that stops short of the sphere is clear; one through it is not.
    top = np.array([[0.0, 200.0, 0.0]])
    assert occ.segments_clear(top, top - [[0.0, 50.0, 0.0]])[0]
    assert not occ.segments_clear(top, np.array([[0.0, 0.1, 0.0]]))[0]
