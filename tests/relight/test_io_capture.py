"""Capture folders (write/read/lazy chunks, atomic, errors naming the file) and
the DiLiGenT reader checked against the benchmark's published baseline."""

import json
import os
import shutil

import numpy as np
import pytest

from relight.io import (
    ImageFormatError,
    lambert_normals,
    open_capture,
    read_capture,
    read_diligent,
    write_capture,
    write_exr_channels,
)


@pytest.fixture
def capture():
    rng = np.random.default_rng(11)
    V, L, P = 2, 4, 24
    radiance = rng.uniform(0, 50, (V, L, P, 3)).astype(np.float32)
    valid = rng.random((V, L, P)) > 0.2
    rig = {
        "directions": rng.normal(size=(L, 3)),
        "intensities": rng.uniform(1, 2, (L, 3)),
        "solid_angles": np.full(L, np.pi),
        "distant": True,
    }
    cameras = [{"name": f"cam{v}", "extrinsics": np.eye(4).tolist(), "resolution": [6, 4]} for v in range(V)]
    return radiance, valid, rig, cameras


def test_capture_roundtrip(tmp_path, capture):
    radiance, valid, rig, cameras = capture
    folder = tmp_path / "cap"
    write_capture(folder, radiance, rig, cameras, valid=valid, metadata={"exposure_s": 0.01}, sample_shape=(4, 6))
    assert sorted(os.listdir(tmp_path)) == ["cap"]  # no temporary left behind
    data = read_capture(folder)
    np.testing.assert_array_equal(data.radiance, radiance)
    np.testing.assert_array_equal(data.valid, valid)
    np.testing.assert_array_equal(data.rig["directions"], rig["directions"])
    assert data.rig["distant"] is True and data.cameras == cameras
    assert data.metadata == {"exposure_s": 0.01} and data.sample_shape == (4, 6)
    # Half storage: 11-bit precision.
    write_capture(tmp_path / "half", radiance, rig, cameras, half=True)
    half = read_capture(tmp_path / "half")
    assert half.valid is None
    np.testing.assert_allclose(half.radiance, radiance, rtol=2.0**-11)
    assert read_capture(tmp_path / "half", dtype=None).radiance.dtype == np.float16


def test_lazy_access_in_chunks(tmp_path, capture):
    radiance, valid, rig, cameras = capture
    write_capture(tmp_path / "cap", radiance, rig, cameras, valid=valid)
    reader = open_capture(tmp_path / "cap")
    assert reader.shape == radiance.shape
    # Chunks of samples reassemble the stack (CaptureSource.read); subsets select views/lights.
    chunks = [reader.read(samples=slice(s, s + 10)) for s in range(0, 24, 10)]
    np.testing.assert_array_equal(np.concatenate([r for r, _ in chunks], axis=2), radiance)
    np.testing.assert_array_equal(np.concatenate([m for _, m in chunks], axis=2), valid)
    np.testing.assert_array_equal(reader.read_mask(samples=slice(5, 20)), valid[:, :, 5:20])
    sub, sub_mask = reader.read(views=[1], lights=[3, 0])
    np.testing.assert_array_equal(sub, radiance[1][[3, 0]][None])
    np.testing.assert_array_equal(sub_mask, valid[1][[3, 0]][None])
    part = read_capture(tmp_path / "cap", views=[1], lights=[3, 0])
    np.testing.assert_array_equal(part.radiance, radiance[1][[3, 0]][None])
    np.testing.assert_array_equal(part.rig["intensities"], rig["intensities"][[3, 0]])
    # Streaming light by light relights with O(one image) memory.
    w = np.arange(1, 5, dtype=np.float64)[:, None] * np.ones((4, 3))
    acc = sum(w[l] * rad for l, rad, _ in reader.iter_lights(view=1))
    np.testing.assert_allclose(acc, np.einsum("lpc,lc->pc", radiance[1], w), rtol=1e-6)


def test_rewrite_is_atomic_and_refuses_foreign_folders(tmp_path, capture):
    radiance, valid, rig, cameras = capture
    folder = tmp_path / "cap"
    write_capture(folder, radiance, rig, cameras)
    bad = radiance.copy()
    bad[1, 2, 3, 0] = np.nan
    with pytest.raises(ImageFormatError, match=r"cap.*NaN.*\(1, 2, 3, 0\)"):
        write_capture(folder, bad, rig, cameras)
    np.testing.assert_array_equal(read_capture(folder).radiance, radiance)  # old capture intact
    write_capture(folder, radiance * 2, rig, cameras)
    np.testing.assert_array_equal(read_capture(folder).radiance, radiance * 2)
    assert sorted(os.listdir(tmp_path)) == ["cap"]
    (tmp_path / "other").mkdir()
    with pytest.raises(FileExistsError, match="not a capture folder"):
        write_capture(tmp_path / "other", radiance, rig, cameras)


def test_capture_errors_name_the_file(tmp_path, capture):
    radiance, valid, rig, cameras = capture
    folder = tmp_path / "cap"
    write_capture(folder, radiance, rig, cameras, valid=valid)

    def broken(name):
        dst = tmp_path / name
        shutil.copytree(folder, dst)
        return dst

    f = broken("rig_mismatch")
    rig5 = json.loads((f / "rig.json").read_text())
    rig5["directions"].append([0, 0, 1])
    (f / "rig.json").write_text(json.dumps(rig5))
    with pytest.raises(ImageFormatError, match=r"rig_mismatch/rig\.json: 5 lights in the rig but .* 4 light images"):
        open_capture(f)

    f = broken("missing_file")
    os.remove(f / "views" / "v001" / "l002.exr")
    with pytest.raises(ImageFormatError, match=r"missing.*v001/l002\.exr"):
        open_capture(f)

    f = broken("no_green")
    path = f / "views" / "v000" / "l001.exr"
    write_exr_channels(path, {"R": np.ones((1, 24)), "B": np.ones((1, 24)), "valid": np.ones((1, 24))})
    with pytest.raises(ImageFormatError, match=r"l001\.exr: channel\(s\) \['G'\] missing"):
        read_capture(f)

    f = broken("negative")
    path = f / "views" / "v001" / "l000.exr"
    write_exr_channels(path, {c: -np.ones((1, 24)) for c in "RGB"} | {"valid": np.ones((1, 24))},
                       header={"relight.view": 1, "relight.light": 0})
    with pytest.raises(ImageFormatError, match=r"v001/l000\.exr: radiance has 72 negative"):
        read_capture(f)

    f = broken("swapped")
    os.replace(f / "views" / "v000" / "l000.exr", f / "views" / "v000" / "tmp.exr")
    os.replace(f / "views" / "v000" / "l003.exr", f / "views" / "v000" / "l000.exr")
    os.replace(f / "views" / "v000" / "tmp.exr", f / "views" / "v000" / "l003.exr")
    with pytest.raises(ImageFormatError, match=r"l000\.exr: header says view 0 light 3"):
        read_capture(f)

    with pytest.raises(ValueError, match="rig has 4 lights but radiance has 3"):
        write_capture(tmp_path / "x", radiance[:, :3], rig, cameras)


def test_capture_image_paths_stay_inside_the_folder(tmp_path, capture):
    """capture.json's ``files`` template is read from the user's file: a template
    leading out of the folder (``..``, absolute, a link), using other fields
    than {view} / {light}, or attribute access, is refused naming the field."""
    radiance, valid, rig, cameras = capture
    folder = tmp_path / "cap"
    write_capture(folder, radiance, rig, cameras, valid=valid)
    outside = tmp_path / "outside"
    shutil.copytree(folder / "views", outside)
    for k, files in enumerate(["../outside/v{view:03d}/l{light:03d}.exr",
                               str(outside) + "/v{view:03d}/l{light:03d}.exr", "views/v{view.real}/l{light:03d}.exr",
                               "views/{x}/l{light:03d}.exr", "views/v000.exr", "views/v{view:03d}/l{light",
                               # format specs that ints refuse, nest an attribute, build a megabyte path,
                               # or give a NUL byte (which os calls refuse with their own ValueError)
                               "views/{light:s}.exr", "views/{light:{view.real}}.exr", "{light:>999999}.exr",
                               "views/{light:{light}{light}{light}}.exr",  # the light index as a width
                               "views/\x00{light}.exr", "v/" * 600 + "{light}.exr"]):
        f = tmp_path / f"bad{k}"
        shutil.copytree(folder, f)
        info = json.loads((f / "capture.json").read_text())
        info["files"] = files
        (f / "capture.json").write_text(json.dumps(info))
        with pytest.raises(ImageFormatError, match=r"capture\.json: field 'files'"):
            open_capture(f)
    # A link inside the folder that resolves outside it.
    f = tmp_path / "linked"
    shutil.copytree(folder, f)
    shutil.rmtree(f / "views")
    os.symlink(outside, f / "views")
    with pytest.raises(ImageFormatError, match="through a link"):
        open_capture(f)


def test_diligent_ball_reproduces_the_benchmark_baseline(shared_data):
    """The README's Lambertian least-squares recipe gives 4.10 deg mean angular
    error on ballPNG; it does only if the 16 bits, the intensities, the mask
    and the normals' frame are all read correctly."""
    d = read_diligent(shared_data / "diligent" / "ballPNG")
    assert d.images.shape == (96, 158, 158, 3) and d.images.dtype == np.float32
    assert d.normals_gt is not None and d.mask.dtype == bool
    n = lambert_normals(d)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    err = np.degrees(np.arccos(np.clip(np.sum(n * d.normals_gt[d.mask], axis=1), -1, 1)))
    assert abs(err.mean() - 4.10) < 0.005  # the published value, to its 2 decimals


def test_diligent_errors(shared_data, tmp_path):
    src = shared_data / "diligent" / "ballPNG"
    dst = tmp_path / "ball"
    dst.mkdir()
    for name in ["001.png", "002.png", "mask.png"]:
        shutil.copy(src / name, dst / name)
    lines = (src / "light_directions.txt").read_text().splitlines()
    (dst / "light_directions.txt").write_text("\n".join(lines[:3]))
    (dst / "light_intensities.txt").write_text("\n".join((src / "light_intensities.txt").read_text().splitlines()[:2]))
    (dst / "filenames.txt").write_text("001.png\n002.png\n")
    with pytest.raises(ImageFormatError, match=r"light_directions\.txt: 3 lights listed but 2 images"):
        read_diligent(dst)
    (dst / "light_directions.txt").write_text("\n".join(lines[:2]))
    d = read_diligent(dst)
    assert d.images.shape[0] == 2 and d.normals_gt is None
