"""``relight render PHOTOS_DIR``: image-based relighting of a camera-space photo
capture (docs/capture_layout.md), camera by camera, without geometry."""

import json
import shutil

import numpy as np
import pytest

import stage
from relight.cli import main
from relight.envmap import load_envmap, rotation_matrix, rotation_sweep_weights
from relight.io import read_exr, write_exr, write_photo_capture

L, H, W = 42, 10, 14
C_ENV = 0.75  # radiance of the constant environment


@pytest.fixture
def const_env(tmp_path):
    path = tmp_path / "const.exr"
    write_exr(path, np.full((16, 32, 3), C_ENV, np.float32))
    return path


@pytest.fixture
def grad_env(tmp_path):
    """A map with structure (brighter toward +x), so rotations change the weights."""
    rows, cols = np.meshgrid(np.arange(16), np.arange(32), indexing="ij")
    img = np.stack([1.0 + np.sin(2 * np.pi * (cols + 0.5) / 32), 0.5 + rows / 16.0, np.ones_like(rows * 1.0)], -1)
    path = tmp_path / "grad.exr"
    write_exr(path, img.astype(np.float32))
    return path


@pytest.fixture
def rig():
    return stage.geodesic_dome(2)  # 162 distant lights, irradiance 1 each


def _photos(tmp_path, rig, values, **kw):
    """A photo capture of 2 cameras whose image under light l is the constant values[l]."""
    cams = stage.camera_ring(2, 1000.0, width=W, height=H)
    n = rig.num_lights
    imgs = [np.broadcast_to(np.asarray(values, np.float32).reshape(n, 1, 1, -1), (n, H, W, 3)).copy()
            for _ in cams]
    return write_photo_capture(tmp_path / "photos", imgs, rig, cams, names=["left", "right"], **kw), imgs


def test_constant_env_gives_the_closed_form(tmp_path, const_env, rig):
    a = 0.2
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, a))
    out = tmp_path / "out"
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet"]) == 0
    for cam in ("left", "right"):
        img = read_exr(out / cam / "relit.exr", channels=["R", "G", "B", "A"])
        # sum_l w_l E_l = the map's integral 4 pi c (Voronoi cells, energy conserved), E_l = 1:
        np.testing.assert_allclose(img[..., :3], a * 4 * np.pi * C_ENV, rtol=1e-4)
        np.testing.assert_array_equal(img[..., 3], 1.0)
        assert (out / cam / "relit.png").is_file()
    settings = json.loads((out / "settings.json").read_text())["resolved"]
    assert settings["input_kind"] == "photos" and settings["cameras"] == ["left", "right"]


def test_per_light_values_are_the_weighted_sum(tmp_path, grad_env, rig):
    values = np.linspace(0.1, 1.0, rig.num_lights)
    exposure = [np.full(rig.num_lights, 2.0), 0.5]
    folder, imgs = _photos(tmp_path, rig, values, exposure=exposure)
    out = tmp_path / "out"
    assert main(["render", str(folder), "--envmap", str(grad_env), "--rotate", "30", "--out", str(out),
                 "--quiet"]) == 0
    env = load_envmap(grad_env)
    R = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(30.0)), np.float64)[None]
    w = np.asarray(rotation_sweep_weights(env, rig.directions, rig.center_irradiance, R), np.float64)[0]  # [L, 3]
    for cam, e in (("left", 2.0), ("right", 0.5)):
        img = read_exr(out / cam / "relit.exr", channels=["R", "G", "B"])
        np.testing.assert_allclose(img, np.broadcast_to(w.T @ values / e, img.shape), rtol=1e-4)


def test_turntable_frames_and_masking(tmp_path, grad_env, rig):
    n = rig.num_lights
    cams = stage.camera_ring(2, 1000.0, width=W, height=H)
    rng = np.random.default_rng(3)
    imgs = [rng.uniform(0.0, 1.0, (n, H, W, 3)).astype(np.float32) for _ in cams]
    imgs[0][5, 1, 5] = 2.0  # saturated under light 5 only
    mask = np.ones((H, W), bool)
    mask[:, :3] = False
    folder = write_photo_capture(tmp_path / "photos", imgs, rig, cams, masks=[mask, None], saturation=1.5)
    out = tmp_path / "out"
    assert main(["render", str(folder), "--envmap", str(grad_env), "--frames", "3", "--out", str(out),
                 "--quiet"]) == 0
    for cam in ("cam000", "cam001"):
        names = sorted(p.name for p in (out / cam).iterdir())
        assert names == [f"relit_{k:03d}.{ext}" for k in range(3) for ext in ("exr", "png")]
    f0 = read_exr(out / "cam000" / "relit_000.exr", channels=["R", "G", "B", "A"])
    assert np.all(f0[:, :3] == 0) and np.all(f0[:, 3:, :3] > 0)  # masked pixels are 0 with coverage 0
    assert 0.0 < f0[1, 5, 3] < 1.0  # the saturated observation is left out of the coverage
    cov = f0[..., 3].copy()
    cov[1, 5] = 1.0
    np.testing.assert_array_equal(cov[:, 3:], 1.0)
    frames = [read_exr(out / "cam001" / f"relit_{k:03d}.exr", channels=["R", "G", "B"]) for k in range(3)]
    assert not np.allclose(frames[0], frames[1])  # the map turned
    # frame k is the 120k-degree rotation
    env = load_envmap(grad_env)
    R = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(240.0)), np.float64)[None]
    w = np.asarray(rotation_sweep_weights(env, rig.directions, rig.center_irradiance, R), np.float32)[0]
    np.testing.assert_allclose(frames[2], np.einsum("lc,lhwc->hwc", w, imgs[1]), rtol=1e-4, atol=1e-6)


def test_npy_rig_needs_units(tmp_path, const_env, shared_data):
    src = shared_data / "lightstage" / "openillumination_light_pos.npy"
    rig = stage.load_rig_file(src, units="directions", up="-y")
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, 0.5))
    shutil.copy(src, folder / "lights.npy")
    doc = json.loads((folder / "capture.json").read_text())
    doc["rig"] = "lights.npy"
    (folder / "capture.json").write_text(json.dumps(doc))
    out = tmp_path / "out"
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet"]) == 1
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet",
                 "--rig-units", "directions"]) == 1
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet",
                 "--rig-units", "directions", "--rig-up=-y"]) == 0
    img = read_exr(out / "left" / "relit.exr", channels=["R", "G", "B"])
    np.testing.assert_allclose(img, 0.5 * 4 * np.pi * C_ENV, rtol=1e-4)


def test_npy_rig_errors_are_reported(tmp_path, const_env, shared_data, capsys):
    src = shared_data / "lightstage" / "openillumination_light_pos.npy"
    rig = stage.load_rig_file(src, units="directions", up="-y")
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, 0.5))
    shutil.copy(src, folder / "lights.npy")
    doc = json.loads((folder / "capture.json").read_text())
    doc["rig"] = {"file": "lights.npy", "up": "-y"}
    (folder / "capture.json").write_text(json.dumps(doc))
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(tmp_path / "o"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "relight render: error:" in err and "lights.npy" in err and "--rig-units" in err


def test_photo_capture_refuses_model_flags(tmp_path, const_env, rig, capsys):
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, 0.5))
    for extra in (["--method", "dense"], ["--camera", "front"], ["--rig", "lsx"]):
        assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(tmp_path / "o"),
                     "--quiet", *extra]) == 1
        assert "photo capture" in capsys.readouterr().err


def test_simulate_image_space_round_trip(tmp_path, const_env, grad_env):
    """relight simulate --space image writes a photo capture that relight render relights."""
    from relight.io import read_photo_capture
    from stage import front_camera

    mesh = stage.load_head()
    front = front_camera(mesh, 16)
    c = np.asarray(mesh.vertices, np.float64)
    centre = 0.5 * (c.min(0) + c.max(0))
    eye = np.asarray(front.center, np.float64) - centre
    turn = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(35.0)), np.float64)
    side = stage.look_at(turn @ eye + centre, tuple(centre), fov_deg=11.0, width=16, height=16)
    stage.save_cameras(tmp_path / "cams.json", [front, side])
    photos = tmp_path / "photos"
    assert main(["simulate", "--space", "image", "--rig", "dome:42", "--camera", str(tmp_path / "cams.json"),
                 "--out", str(photos), "--quiet"]) == 0
    cap = read_photo_capture(photos)
    assert cap.n_views == 2 and cap.n_lights == 42 and cap.names == ["cam000", "cam001"]
    views = list(cap)
    for v in views:
        assert v.radiance.shape == (42, 16, 16, 3) and 20 < v.mask.sum() < 256
        assert np.all(v.radiance[:, ~v.mask] == 0) and v.radiance[:, v.mask].max() > 0
    out = tmp_path / "relit"
    assert main(["render", str(photos), "--envmap", str(grad_env), "--frames", "2", "--out", str(out),
                 "--quiet"]) == 0
    env = load_envmap(grad_env)
    rots = np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                     for a in (0.0, 180.0)])
    w = np.asarray(rotation_sweep_weights(env, cap.rig.directions, cap.rig.center_irradiance, rots), np.float64)
    for name, v in zip(cap.names, views, strict=True):
        for k in range(2):
            img = read_exr(out / name / f"relit_{k:03d}.exr", channels=["R", "G", "B", "A"])
            want = np.einsum("lc,lhwc->hwc", w[k], v.radiance.astype(np.float64))
            np.testing.assert_allclose(img[..., :3], want, rtol=1e-4, atol=1e-7)
            np.testing.assert_array_equal(img[..., 3], v.mask.astype(np.float32))
    # simulate refuses to replace a folder that is not a photo capture
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "keep.txt").write_text("x")
    assert main(["simulate", "--space", "image", "--rig", "dome:12", "--image-size", "8", "--out",
                 str(tmp_path / "other"), "--quiet"]) == 1
    assert (tmp_path / "other" / "keep.txt").is_file()


@pytest.mark.parametrize("name", ["../ESCAPED", "ABSOLUTE", "a/b", "..", ".", "c:evil", "x\x00y",
                                  "tab\there", "\\\\server\\share", "", "n" * 256])
def test_a_camera_name_that_is_not_a_plain_file_name_is_refused(tmp_path, const_env, rig, capsys, name):
    """issue 29, item 1: a camera's name becomes its folder under --out (OUT/<name>/relit.exr), so a name from
    cameras.json must be one plain file-name component (relight.io._errors.file_name). A name with a path
    separator, a drive colon, a control character, '.' or '..', or over 255 bytes is refused naming the file
    and field; nothing is written beside --out or anywhere else ("ABSOLUTE": an absolute path in tmp_path)."""
    name = str(tmp_path / "abs-escaped") if name == "ABSOLUTE" else name
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, 0.2))
    doc = json.loads((folder / "cameras.json").read_text())
    doc["cameras"][0]["name"] = name
    (folder / "cameras.json").write_text(json.dumps(doc))
    info = json.loads((folder / "capture.json").read_text())
    info["views"][0]["camera"] = name
    (folder / "capture.json").write_text(json.dumps(info))
    before = set(tmp_path.rglob("*"))
    out = tmp_path / "nest" / "out"
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet"]) != 0
    err = capsys.readouterr().err
    assert "cameras.json: cameras[0] field 'name'" in err, err
    assert ("not a plain file name" in err) or ("must be a non-empty file name" in err), err
    # Nothing new anywhere but --out and its parent (which the command may make before it reads the capture).
    assert set(tmp_path.rglob("*")) - before <= {tmp_path / "nest", out} | set(out.rglob("*"))
    assert not any(out.rglob("*.exr")) and not (tmp_path / "abs-escaped").exists()


def test_write_photo_capture_refuses_a_name_that_would_leave_its_folder(tmp_path, rig):
    imgs = [np.zeros((rig.num_lights, H, W, 3), np.float32)] * 2
    with pytest.raises(ValueError, match=r"names\[1\].*not a plain file name"):
        write_photo_capture(tmp_path / "p", imgs, rig, stage.camera_ring(2, 1000.0, width=W, height=H),
                            names=["ok", "../up"])
    assert not (tmp_path / "up").exists() and not (tmp_path / "p").exists()


@pytest.mark.parametrize("exposure, message", [(1e-300, "would overflow float32"), (1e-20, "values above 1e+15")])
def test_an_exposure_in_the_wrong_units_is_refused_not_rendered_as_nan(tmp_path, const_env, rig, capsys, exposure,
                                                                        message):
    """issue 29, item 6: ``"exposure": 1e-300`` made radiance = value / (exposure x gain) overflow, and `relight
    render` wrote relit.exr with NaN pixels and exit 0. A scale that overflows float32 is refused at the field;
    one whose radiance passes relight.io's MAX_RADIANCE (1e15) at the first image that does."""
    folder, _ = _photos(tmp_path, rig, np.full(rig.num_lights, 0.2))
    info = json.loads((folder / "capture.json").read_text())
    info["exposure"] = exposure
    (folder / "capture.json").write_text(json.dumps(info))
    out = tmp_path / "out"
    assert main(["render", str(folder), "--envmap", str(const_env), "--out", str(out), "--quiet"]) != 0
    err = capsys.readouterr().err
    assert message in err and ("capture.json" in err or "l000.exr" in err), err
    assert not any(out.rglob("*.exr"))
