"""Texel-space captures and map sets back to stage objects
(``relight.io.load_texel_capture`` / ``load_texel_maps``), including capture
folders written by earlier versions (the CLI's own camera/rig schema, before
``stage.camera_to_dict`` / ``stage.rig_to_dict`` became the one schema), and
errors that name the file and the field."""

import json

import numpy as np
import pytest

import relight
import stage
from relight.io import (
    ImageFormatError,
    load_texel_capture,
    load_texel_maps,
    mesh_spec,
    read_maps,
    texel_surface,
    write_capture,
    write_maps,
)

RES = 8


@pytest.fixture(scope="module")
def head_surface():
    spec = {**mesh_spec(None), "resolution": [RES, RES]}
    mesh, full = texel_surface(spec, RES)
    return spec, mesh, full


def _old_cli_camera(cam, name):
    """A camera as relight/cli/_common.py's camera_to_json wrote it (before the
    schema moved to stage), spelled out by hand."""
    return {"name": name, "model": "orthographic" if cam.orthographic else "pinhole", "width": cam.width,
            "height": cam.height, "K": np.asarray(cam.K, np.float64).tolist(),
            "R": np.asarray(cam.R, np.float64).tolist(), "t": np.asarray(cam.t, np.float64).tolist(),
            "convention": "opencv", "units": "mm"}


def _old_cli_rig(rig):
    """A rig as relight/cli/_common.py's rig_to_json wrote it."""
    return {"positions": np.asarray(rig.position, np.float64).tolist(),
            "intensities": np.asarray(rig.intensity, np.float64).tolist(),
            "solid_angles": np.asarray(rig.solid_angle, np.float64).tolist(), "near_field": bool(rig.near_field),
            "units": {"positions": "mm (distant lights: direction x radius)",
                      "intensities": "radiant intensity (near field) or irradiance at normal incidence (distant)"}}


def _write_texel_capture(folder, spec, full, rig, cameras, radiance=None, valid=None):
    L = rig.num_lights if isinstance(rig, stage.Rig) else len(rig.get("positions", rig.get("directions")))
    V, P = len(cameras), RES * RES
    rng = np.random.default_rng(3)
    if radiance is None:
        radiance = rng.uniform(0.1, 1.0, (V, L, P, 3)).astype(np.float32)
    if valid is None:
        valid = np.zeros((V, L, P), bool)
        valid[..., np.asarray(full.texel_index)] = True
    write_capture(folder, radiance, rig, cameras, valid=valid, sample_shape=(RES, RES),
                  metadata={"space": "texel", "surface": spec})
    return radiance, valid


def test_a_capture_from_stage_objects_round_trips(tmp_path, head_surface):
    spec, mesh, full = head_surface
    rig = stage.geodesic_dome(0)
    cams = stage.camera_ring(2, 1300.0, fov_deg=11.0, width=24, height=24)
    radiance, valid = _write_texel_capture(tmp_path / "cap", spec, full, rig, cams)
    # The capture folder stores the one schema.
    stored = json.loads((tmp_path / "cap" / "cameras.json").read_text())
    assert stored == [stage.camera_to_dict(c, f"cam{i:03d}") for i, c in enumerate(cams)]
    assert json.loads((tmp_path / "cap" / "rig.json").read_text()) == stage.rig_to_dict(rig)
    seen = []
    capture, surface, mesh2, metadata = load_texel_capture(tmp_path / "cap", progress=lambda *a: seen.append(a))
    n = 2 * rig.num_lights
    assert seen == [("read capture", k, n) for k in range(n + 1)]  # stage.Progress: cumulative counts from 0
    assert metadata["surface"]["resolution"] == [RES, RES] and mesh2.faces.shape == mesh.faces.shape
    idx = np.asarray(surface.texel_index)
    np.testing.assert_array_equal(idx, np.asarray(full.texel_index))  # every texel observed
    np.testing.assert_array_equal(np.asarray(capture.radiance), radiance[:, :, idx])
    np.testing.assert_allclose(np.asarray(capture.rig.position), np.asarray(rig.position), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(capture.rig.solid_angle), np.asarray(rig.solid_angle), rtol=1e-6)
    assert capture.rig.near_field == rig.near_field
    for a, b in zip(cams, capture.cameras, strict=True):
        np.testing.assert_allclose(np.asarray(a.K), np.asarray(b.K))
        np.testing.assert_allclose(np.asarray(a.R), np.asarray(b.R))
        assert (a.width, a.height, a.orthographic) == (b.width, b.height, b.orthographic)


def test_texels_without_valid_observations_are_dropped(tmp_path, head_surface):
    spec, _, full = head_surface
    rig = stage.geodesic_dome(0)
    cams = (stage.look_at((0.0, 0.0, 1300.0), fov_deg=11.0, width=24, height=24),)
    idx = np.asarray(full.texel_index)
    valid = np.zeros((1, rig.num_lights, RES * RES), bool)
    valid[0, 3, idx[::2]] = True
    _write_texel_capture(tmp_path / "cap", spec, full, rig, cams, valid=valid)
    capture, surface, _, _ = load_texel_capture(tmp_path / "cap")
    np.testing.assert_array_equal(np.asarray(surface.texel_index), idx[::2])
    assert np.asarray(capture.mask).sum() == len(idx[::2])


def test_capture_folders_in_the_old_cli_schema_still_load(tmp_path, head_surface):
    """rig.json / cameras.json hand-written as the CLI wrote them before the
    schema moved to stage (per-camera convention/units, rig_to_json), and a
    rig given by unnormalised 'directions' (capture folders from other tools)."""
    spec, _, full = head_surface
    rig = stage.light_stage_x().subset(np.arange(0, 346, 40))
    cams = stage.camera_ring(2, 1300.0, fov_deg=11.0, width=24, height=24, arc_deg=60.0)
    _write_texel_capture(tmp_path / "old", spec, full, _old_cli_rig(rig),
                         [_old_cli_camera(c, f"cam{i:03d}") for i, c in enumerate(cams)])
    capture, _, _, _ = load_texel_capture(tmp_path / "old")
    assert capture.rig.near_field
    np.testing.assert_allclose(np.asarray(capture.rig.position), np.asarray(rig.position), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(capture.rig.intensity), np.asarray(rig.intensity), rtol=1e-6)
    for a, b in zip(cams, capture.cameras, strict=True):
        np.testing.assert_allclose(np.asarray(b.t), np.asarray(a.t), rtol=1e-6)
    # The same cameras.json is also a valid --camera file (stage.load_cameras).
    assert len(stage.load_cameras(tmp_path / "old" / "cameras.json")) == 2

    dirs = {"directions": (3.0 * np.asarray(stage.geodesic_dome(0).directions)).tolist(),
            "intensities": [[2.0, 2.0, 2.0]] * 12, "distant": True}
    _write_texel_capture(tmp_path / "dirs", spec, full, dirs, [_old_cli_camera(cams[0], "front")])
    capture, _, _, _ = load_texel_capture(tmp_path / "dirs")
    assert not capture.rig.near_field
    np.testing.assert_allclose(np.linalg.norm(np.asarray(capture.rig.position), axis=1), 1000.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(capture.rig.intensity), 2.0)


def test_capture_errors_name_the_file_and_the_field(tmp_path, head_surface):
    spec, _, full = head_surface
    rig = stage.geodesic_dome(0)
    cam = stage.look_at((0.0, 0.0, 1300.0), fov_deg=11.0, width=24, height=24)

    # Free-form camera dicts (write_capture allows them) are not cameras.
    _write_texel_capture(tmp_path / "free", spec, full, rig, [{"name": "cam0", "extrinsics": np.eye(4).tolist()}])
    with pytest.raises(ValueError, match=r"free/cameras\.json: camera 0: missing field 'K'"):
        load_texel_capture(tmp_path / "free")

    bad = stage.camera_to_dict(cam)
    bad["units"] = "inches"
    _write_texel_capture(tmp_path / "units", spec, full, rig, [bad])
    with pytest.raises(ValueError, match=r"units/cameras\.json: camera 0: field 'units' must be 'mm'"):
        load_texel_capture(tmp_path / "units")

    _write_texel_capture(tmp_path / "rig", spec, full, {"positions": np.asarray(rig.position).tolist(),
                                                        "near_field": "maybe"}, [cam])
    with pytest.raises(ValueError, match=r"rig/rig\.json: field 'near_field' must be true or false"):
        load_texel_capture(tmp_path / "rig")

    write_capture(tmp_path / "image", np.ones((1, rig.num_lights, 4, 3), np.float32), rig, [cam],
                  metadata={"space": "image"})
    with pytest.raises(ImageFormatError, match=r"image/capture\.json: not a texel-space capture"):
        load_texel_capture(tmp_path / "image")

    write_capture(tmp_path / "size", np.ones((1, rig.num_lights, 4, 3), np.float32), rig, [cam],
                  metadata={"space": "texel", "surface": spec}, sample_shape=(2, 2))
    with pytest.raises(ImageFormatError, match=r"size/capture\.json: images are \(2, 2\) but the texel grid is"):
        load_texel_capture(tmp_path / "size")

    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_texel_capture(tmp_path / "nowhere")


def test_map_sets_load_with_their_surface_cameras_and_rig(tmp_path, head_surface):
    spec, mesh, full = head_surface
    surface = full.subset(np.arange(0, full.num_samples, 3))
    rng = np.random.default_rng(5)
    P = surface.num_samples
    maps = relight.material_maps(surface, rng.uniform(0.1, 0.9, (P, 3)), np.full((P, 1), 0.03),
                                 rng.uniform(0.2, 0.5, (P, 1)))
    rig = stage.geodesic_dome(0)
    cam = stage.look_at((0.0, 0.0, 1300.0), fov_deg=11.0, width=24, height=24)
    folder = tmp_path / "maps"
    folder.mkdir()
    stage.save_rig(folder / "rig.json", rig)
    write_maps(folder, maps, surface, surface_info=spec,
               metadata={"cameras": [stage.camera_to_dict(cam, "cam000")], "rig": "rig.json"})
    loaded = load_texel_maps(folder)
    np.testing.assert_array_equal(np.asarray(loaded.surface.texel_index), np.asarray(surface.texel_index))
    np.testing.assert_allclose(np.asarray(loaded.maps.rho_d), np.asarray(maps.rho_d), rtol=1e-6)
    assert len(loaded.cameras) == 1 and loaded.cameras[0].width == 24
    np.testing.assert_allclose(np.asarray(loaded.rig.position), np.asarray(rig.position), rtol=1e-6)
    assert loaded.mesh.faces.shape == mesh.faces.shape
    textures, _ = read_maps(folder)
    assert loaded.textures.resolution == textures.resolution


def test_mesh_units_and_placement(tmp_path):
    """The bundled head and a byte-identical copy of its file are placed alike
    (the scan's own scale and centring); --units / --scale set mm per file unit."""
    import shutil

    from relight.io import MESH_UNITS, mesh_size_warning, spec_mesh

    copy = tmp_path / "my_head.glb"
    shutil.copyfile(stage.head_mesh_path(), copy)
    bundled, mine = spec_mesh(mesh_spec(None)), spec_mesh(mesh_spec(copy))
    np.testing.assert_array_equal(bundled.vertices, mine.vertices)
    as_is = spec_mesh(mesh_spec(copy, scale=1.0, center=False))
    extent = np.ptp(as_is.vertices, axis=0)
    np.testing.assert_allclose(np.ptp(bundled.vertices, axis=0), stage.HEAD_SCALE_MM * extent, rtol=1e-5)
    assert MESH_UNITS == {"mm": 1.0, "cm": 10.0, "m": 1000.0}
    assert mesh_spec(copy, units="cm")["scale"] == 10.0 and mesh_spec(copy, units="m")["scale"] == 1000.0
    # An implausible size for the rig is named, with the flag that fixes it; the placed head is plausible.
    rig = stage.light_stage_x()
    msg = mesh_size_warning(as_is, rig)
    assert msg is not None and "--units" in msg and "mm across" in msg
    assert mesh_size_warning(bundled, rig) is None
    assert mesh_size_warning(as_is, stage.geodesic_dome(1)) is None  # distant lights: no radius to compare with


@pytest.mark.parametrize("kwargs, match", [
    ({"units": "cm", "scale": 2.0}, "not both"),
    ({"units": "inch"}, "units must be one of"),
    ({"scale": 0.0}, "positive finite"),
    ({"scale": float("nan")}, "positive finite"),
])
def test_mesh_placement_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mesh_spec(None, **kwargs)
