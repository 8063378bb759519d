"""The results viewer (``relight view``, ``relight.view``; issue 18): every command's output folder holds an
``index.html`` that loads in a real browser (headless Chromium) with no console error and whose rotation slider
changes the displayed image; the page is self-contained (``data:`` images only, no network) and listed in the
folder's manifest; ``relight view`` rewrites it with a finer sweep; the sweep is the project's image-based
relighting of each rotation; report.md is rendered with its markup escaped.

One tiny output per command, made once for the module: simulate (the head at 12 x 12 texels under a 42-light
dome, one 32 x 32 camera), fit (Gauss-Newton), render of the map set and a 4-frame turntable of the capture;
the demo is the run's one (conftest's demo_output, 32 x 32 texels, 1 camera), whose physics test_cli.py
tests and whose page is tested here.
The browser tests skip, saying why, where Chromium is absent (``.ci/run`` installs it). The pages of map sets
(the fit's and the demo's) hold a WebGL2 "3D view" (relight/view/_page3d.py): its self-test runs in the same
browser launch as the page's (Chromium's SwiftShader WebGL), and one launch per page serves every test here."""

import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from relight.cli import main

RES = 12
SIZE = 32
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium is not installed (Debian: apt-get "
                                                             "install chromium; .ci/run installs it)")


@pytest.fixture(scope="module")
def outputs(tmp_path_factory, demo_output):
    root = tmp_path_factory.mktemp("view")
    assert main(["simulate", "--rig", "dome:42", "--resolution", str(RES), "--image-size", str(SIZE),
                 "--out", str(root / "cap"), "-qq"]) == 0
    assert main(["fit", str(root / "cap"), "--model", "ggx", "--out", str(root / "maps"), "--solver", "gn", "-qq"]) == 0
    assert main(["render", str(root / "maps"), "--out", str(root / "rend"), "-qq"]) == 0
    assert main(["render", str(root / "cap"), "--out", str(root / "turn"), "--frames", "4", "-qq"]) == 0
    shutil.copytree(demo_output, root / "demo")  # a copy: the shared run's folder stays as the demo wrote it
    return root


# Headless Chromium with WebGL2 on SwiftShader (its CPU rasteriser): without --enable-unsafe-swiftshader a page that
# creates a WebGL context gets a deprecation message on its console.
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--no-first-run")
# The one console line a page may print: the driver's performance note on the self-test's own gl.readPixels
# (synchronous readback is what a self-test does; an interactive page never reads pixels back).
READBACK_NOTE = "GPU stall due to ReadPixels"
_RESULTS: dict = {}


def _selftest(page: Path, profile: Path) -> tuple[dict, list[str]]:
    """Open ``page#selftest`` in headless Chromium; (the page's self-test result, the console lines but the
    readback note). Tried twice: on a loaded machine a first start of a fresh profile can end its virtual time
    before the page's load event. One launch per version of a page (kept by path, size and time)."""
    st = page.stat()
    key = (str(page.resolve()), st.st_size, st.st_mtime_ns)
    if key in _RESULTS:
        return _RESULTS[key]
    for attempt in range(2):
        out = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}-{attempt}",
                              "--virtual-time-budget=30000", "--enable-logging=stderr", "--v=0", "--dump-dom",
                              page.resolve().as_uri() + "#selftest"], capture_output=True, text=True, timeout=180)
        m = re.search(r'<pre id="selftest-result">(.*?)</pre>', out.stdout, re.S)
        if m:
            break
    assert m, f"no self-test result in the DOM (rc {out.returncode}): {out.stderr[-1500:]}"
    console = [line for line in out.stderr.splitlines() if ":CONSOLE" in line and READBACK_NOTE not in line]
    _RESULTS[key] = json.loads(html.unescape(m.group(1))), console
    return _RESULTS[key]


# ---------------------------------------------------------------- in the browser


@needs_chromium
@pytest.mark.parametrize("name, sweeps", [("cap", 1), ("maps", 2), ("rend", 1), ("turn", 1), ("demo", 1)])
def test_every_commands_page_loads_and_its_slider_moves_the_image(outputs, tmp_path, name, sweeps):
    result, console = _selftest(outputs / name / "index.html", tmp_path / "profile")
    assert result["errors"] == [] and console == [], (result, console)
    assert result["sweeps"] == sweeps and result["frames"] >= 4
    assert result["broken"] == 0 and result["images"] >= 2  # every embedded image decoded
    assert result["before"] != result["after"], "the slider did not change the displayed image"
    assert result["width"] > 0 and result.get("moved_width", result["width"]) == result["width"]
    if name not in ("maps", "demo"):  # the 3D view is on the pages of map sets only
        assert "view3d" not in result
        return
    v = result["view3d"]
    assert v["webgl2"] and v["failure"] is None and v["gl_errors"] == [], v
    assert 0.05 < v["covered"] < 0.9  # the head is drawn, inside the frame
    # Turning the environment by 90 degrees and orbiting by 40 (20 up) change the picture, on much of the head.
    hashes = v["hashes"]
    assert len({hashes["base"], hashes["rotated"], hashes["orbited"], hashes["pitched"]}) == 4
    assert v["changed"]["rotation"] > 0.3 * v["covered"] and v["changed"]["orbit"] > 0.3 * v["covered"]
    # Every switch draws: 6 maps each of the fit, the truth and the error (both pages have a truth); the fit's
    # shaded, albedo, F0 and roughness views differ from each other, and fit, truth and error differ shaded.
    # (Maps equal in fit and truth draw alike: the maps fit's normals are the mesh's, it has no mean free path.)
    m = v["modes"]
    assert len(m) == 18
    assert len({m[f"fit/{k}"] for k in ("shaded", "albedo", "f0", "roughness")}) == 4
    assert len({m["fit/shaded"], m["truth/shaded"], m["error/shaded"]}) == 3
    if name == "demo":  # subsurface on both sides: the mean free path shows, and differs
        assert len({m["fit/mfp"], m["truth/mfp"], m["error/mfp"]}) == 3
    # The controls, driven by events: a 50 x 20 px drag orbits by 0.01 rad a pixel, a wheel notch of 200 zooms
    # out by exp(0.2), the slider, map selector and error switch set the state, a double click goes home.
    it = v["interaction"]
    assert it["yaw"] == pytest.approx(-0.5) and it["pitch"] == pytest.approx(0.2) and it["dragged"]
    assert it["zoom"] == pytest.approx(np.exp(0.2)) and it["home"]
    assert (it["rot"], it["mode"], it["source"]) == (45, 1, 2)


@needs_chromium
def test_relight_view_rewrites_the_page_with_capture_and_model_rows(outputs, tmp_path, capsys):
    """`relight view` of a fit: its capture relit image-based and the fitted maps model-based, one slider; the
    manifest lists the new page and still checks."""
    from relight.results import open_result_set

    assert main(["view", str(outputs / "maps"), "--frames", "6", "--size", "24"]) == 0
    assert "2 sweep(s) of 6 rotations" in capsys.readouterr().out
    result, console = _selftest(outputs / "maps" / "index.html", tmp_path / "profile")
    assert result["errors"] == [] and console == [] and result["sweeps"] == 2 and result["frames"] == 6
    assert result["before"] != result["after"]
    s = open_result_set(outputs / "maps")
    s.check()
    assert "index.html" in s.files


def _sphere_surface(normals: np.ndarray):
    """A stage.Surface of P samples with these normals (positions on a 50 mm sphere, any tangent frame)."""
    import jax.numpy as jnp

    import brdf
    import stage

    n = jnp.asarray(normals, jnp.float32)
    t, b = brdf.orthonormal_basis(n)
    P = len(normals)
    return stage.Surface(position=50.0 * n, normal=n, tangent=t, bitangent=b, uv=jnp.zeros((P, 2), jnp.float32),
                         area=jnp.ones(P, jnp.float32), texel_index=jnp.arange(P, dtype=jnp.int32),
                         face=jnp.zeros(P, jnp.int32), resolution=(1, P))


# The sphere check's tolerances on the relative error per pixel and channel (the page renders to a float32 target;
# measured at most 0.12% and 0.02% on SwiftShader, docs/cli.md): under a constant environment against relight.render's
# Dense quadrature (an independent integral of Lambert + GGX: the split sum is exact for a constant map, so what is
# left is the DFG table's bilinear lookup, the quadrature's own error and float16 storage); under the page's own
# environment, turned 0 and 90 degrees, against relight.render's Fast, the kernel the shader ports (float16 storage
# of the prefiltered map only): this one holds the SH basis, the lat-long orientation and the rotation's sense.
SPHERE_RTOL_CONSTANT = 0.01
SPHERE_RTOL_FAST = 0.005


@needs_chromium
def test_view3d_sphere_matches_relight_render(outputs, tmp_path):
    from relight import material_maps
    from relight.envmap import EnvMap, bundled_envmap_path, load_envmap
    from relight.materials import GGX
    from relight.render import Dense, render_samples, y_rotations
    from relight.view import view3d_data, view3d_envmap, view3d_method

    page = outputs / "demo" / "index.html"
    result, _ = _selftest(page, tmp_path / "profile")
    sphere = result["view3d"]["sphere"]
    assert result["view3d"]["float_target"], "EXT_color_buffer_float: the check reads float32 pixels"
    assert view3d_data(page.read_text())["environment"]["name"] == bundled_envmap_path().name  # the demo's map
    env_page = view3d_envmap(load_envmap(bundled_envmap_path()))
    env_const = EnvMap(np.full((32, 64, 3), sphere["radiance"], np.float32))
    worst = {}
    for case in sphere["cases"]:
        px = np.asarray(case["pixels"], np.float64)[::3]  # a third of the ~1100 pixels: enough, and quicker
        assert len(px) > 300
        normals = px[:, :3] / np.linalg.norm(px[:, :3], axis=1, keepdims=True)
        assert np.all(np.abs(np.linalg.norm(px[:, :3], axis=1) - 1) < 1e-3)  # the shader's normal, read back
        surf = _sphere_surface(normals)
        P = len(px)
        maps = material_maps(surf, np.tile(np.asarray(case["albedo"], np.float32), (P, 1)),
                             np.full((P, 1), case["f0"], np.float32), np.full((P, 1), case["alpha"], np.float32),
                             model=np.full(P, GGX))
        assert case["model"] == GGX
        view = np.array([0.0, 0.0, 1.0])  # the page's orthographic camera looks down -z
        if case["environment"] == "constant":
            want = render_samples(maps, surf, env_const, view, method=Dense(rows=64))
            rtol = SPHERE_RTOL_CONSTANT
        else:
            want = render_samples(maps, surf, env_page, view, method=view3d_method(),
                                  rotation=y_rotations([case["rotation_deg"]])[0])
            rtol = SPHERE_RTOL_FAST
        want = np.asarray(want, np.float64)
        rel = np.abs(px[:, 3:] - want) / want
        worst[case["name"]] = float(rel.max())
        assert rel.max() < rtol, (case["name"], rel.max(), normals[np.argmax(rel.max(1))])
    assert worst["skin, page environment"] > 0 or worst["skin, page environment turned"] > 0  # floats, not a copy
    # The turned environment is another picture: the comparison above is not blind to the rotation.
    a, b = (np.asarray(c["pixels"])[:, 3:] for c in sphere["cases"][2:4])
    assert np.sum(np.abs(a - b)) > 0.05 * np.sum(b)


# ---------------------------------------------------------------- the page and the manifest


@pytest.mark.parametrize("name", ["cap", "maps", "rend", "turn", "demo"])
def test_the_page_is_self_contained_and_in_the_manifest(outputs, name):
    from relight.results import open_result_set

    page = (outputs / name / "index.html").read_text()
    srcs = re.findall(r"""\bsrc=["']([^"']*)""", page)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs), {s[:40] for s in srcs}
    assert "<link" not in page and not re.search(r"<script[^>]+src=", page)
    assert not re.search(r"""(url\(|href=["'])\s*(https?:|//)""", page)  # nothing fetched from the network
    s = open_result_set(outputs / name)
    s.check()  # the page was written into the set before its manifest
    assert "index.html" in s.files


def test_what_each_page_shows(outputs):
    fit = (outputs / "maps" / "index.html").read_text()
    assert "the capture it was fitted from, relit image-based" in fit  # the fit's own capture, at memory speed
    assert "maps rendered model-based" in fit  # and what the fit made (issue 29: only the capture)
    assert "Truth | fit | error" in fit and "relight fit report" in fit and "<table>" in fit
    # The table itself, built from the maps before the set's manifest exists, not an error in its place (issue
    # 29: "no relight-set.json, so not a complete result set").
    assert "relative error" in fit and "not a complete result set" not in fit and "no truth | fit" not in fit
    assert "<h3>" in fit  # report.md's title, under the page's own headings
    assert "rendered turntable" in (outputs / "turn" / "index.html").read_text()  # its own 4 frames
    demo = (outputs / "demo" / "index.html").read_text()
    assert "the simulated capture relit image-based" in demo and "Truth | fit | error" in demo


def test_the_3d_view_embeds_the_mesh_and_maps(outputs):
    """What the demo page's 3D view holds, decoded here from the page: the map set's mesh exactly (float32,
    uint32), the fitted maps (F0, alpha and rung as float16, albedo and normal as 8-bit PNGs), the truth's, the
    environment's SH as relight.render's Fast prepares it, and the slider's exposure. Only map sets have one."""
    import base64
    import io

    from PIL import Image

    from relight.envmap import bundled_envmap_path, load_envmap
    from relight.image import srgb_encode
    from relight.io import read_maps, spec_mesh
    from relight.view import view3d_data, view3d_envmap, view3d_method

    for name in ("cap", "rend", "turn"):
        page = (outputs / name / "index.html").read_text()
        assert view3d_data(page) is None and 'id="view3d"' not in page
    page = (outputs / "demo" / "index.html").read_text()
    data = view3d_data(page)
    assert 'id="view3d"' in page and set(data["sets"]) == {"fit", "truth"}

    def arr(b64, dtype, *shape):
        return np.frombuffer(base64.b64decode(b64), np.dtype(dtype).newbyteorder("<")).reshape(*shape)

    fit = read_maps(outputs / "demo" / "maps")[0]
    mesh = spec_mesh(fit.info["surface"])
    m = data["mesh"]
    assert m["triangles"] == m["source_triangles"] == len(mesh.faces) < 50_000  # the head: not decimated
    np.testing.assert_array_equal(arr(m["indices"], np.uint32, -1, 3), mesh.faces)
    np.testing.assert_array_equal(arr(m["positions"], np.float32, -1, 3), np.float32(mesh.vertices))
    np.testing.assert_array_equal(arr(m["uv"], np.float32, -1, 2), np.float32(mesh.uv))
    np.testing.assert_array_equal(arr(m["normals"], np.float32, -1, 3), np.float32(mesh.normals))
    h, w = fit.resolution
    assert data["texture_size"] == [w, h]
    for key, tex in (("fit", fit), ("truth", read_maps(outputs / "demo" / "truth")[0])):
        params = arr(data["sets"][key]["params"], np.float16, h, w, 4).astype(np.float64)
        np.testing.assert_allclose(params[..., 0], tex.specular[..., 0], rtol=1e-3, atol=1e-7)  # float16
        np.testing.assert_array_equal(params[..., 2], tex.model)
        seen = tex.coverage
        imgs = {}
        for what in ("albedo", "normal"):
            uri = re.search(rf'id="{data["sets"][key][what]}" alt="" src="data:image/png;base64,([^"]+)"', page)
            imgs[what] = np.asarray(Image.open(io.BytesIO(base64.b64decode(uri.group(1)))), np.float64) / 255
        want = np.asarray(srgb_encode(np.clip(tex.albedo, 0, 1)), np.float64)
        assert np.max(np.abs(imgs["albedo"] - want)[seen]) <= 0.5 / 255 + 1e-9  # 8-bit rounding
        assert np.max(np.abs(2 * imgs["normal"] - 1 - tex.normal)[seen]) <= 1 / 255 + 1e-6
    lighting = view3d_method().prepare(view3d_envmap(load_envmap(bundled_envmap_path())))
    np.testing.assert_allclose(np.reshape(data["environment"]["sh"], (9, 3)), np.asarray(lighting.sh), rtol=1e-5)
    assert data["environment"]["lut_size"] == np.asarray(lighting.lut).shape[0]
    np.testing.assert_allclose(arr(data["environment"]["lut"], np.float32, -1), np.ravel(lighting.lut), atol=1e-6)
    exposure = float(re.search(r"exposure ([+-][0-9.]+) EV", page).group(1))  # the slider's, as it reads
    assert abs(data["exposure"] - exposure) < 0.006


def test_decimate_mesh_keeps_the_bound_the_uvs_and_the_seams():
    """Vertex clustering of the head (17,684 triangles) to at most 2,000: close to the bound, no degenerate
    face, UVs inside the atlas, and no new open edge (seams stay closed: both sides of a seam move to one
    position); the curvature of a sphere of radius R is 1 / R."""
    import stage
    from relight.view import decimate_mesh, vertex_curvature
    from tests.scenes import uv_sphere

    head = stage.load_head()
    small = decimate_mesh(head, 2000)
    assert 1000 < len(small.faces) <= 2000 and decimate_mesh(head, 10**6) is head
    f = small.faces
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    assert np.all((small.uv >= 0) & (small.uv <= 1)) and np.allclose(np.linalg.norm(small.normals, axis=1), 1)

    def open_edges(mesh):  # edges (by position) used by one face only
        _, pid = np.unique(np.round(mesh.vertices, 6), axis=0, return_inverse=True)
        pf = pid.reshape(-1)[mesh.faces]
        e = np.sort(np.concatenate([pf[:, [0, 1]], pf[:, [1, 2]], pf[:, [2, 0]]]), axis=1)
        _, count = np.unique(e, axis=0, return_counts=True)
        return int(np.sum(count == 1))

    assert open_edges(head) == 0 and open_edges(small) == 0  # closed, and still closed
    sphere = uv_sphere(radius=40.0, n_lat=24, n_lon=48)
    k = vertex_curvature(sphere)
    assert np.mean(k > 0) > 0.9  # 0 on the pole's vertices that no edge of positive length reaches
    np.testing.assert_allclose(k[k > 0], 1 / 40.0, rtol=1e-9)


def test_convert_puts_a_page_into_its_output(outputs, tmp_path):
    """convert's output is written by the library's converters; the page goes in afterwards, with the
    capture relit image-based, and the store still reads."""
    from relight.io import load_texel_capture

    assert main(["convert", str(outputs / "cap"), str(tmp_path / "c.zarr"), "-qq"]) == 0
    page = (tmp_path / "c.zarr" / "index.html").read_text()
    assert "window.SWEEPS=" in page and "capture, image-based" in page
    assert load_texel_capture(tmp_path / "c.zarr").capture.radiance.shape[1] == 42


def test_no_index_writes_no_page(outputs, tmp_path):
    assert main(["render", str(outputs / "maps"), "--out", str(tmp_path / "r"), "--no-index", "-qq"]) == 0
    assert (tmp_path / "r" / "relit.exr").is_file() and not (tmp_path / "r" / "index.html").exists()


def test_a_failed_sweep_leaves_a_page_that_says_why(tmp_path, capsys):
    from relight.cli._common import write_index_page

    (tmp_path / "report.md").write_text("# r\n\ntext\n")

    def broken():
        raise ValueError("the capture moved")

    path, n = write_index_page(tmp_path, broken, "view")
    assert n == 0 and "the sweep failed (the capture moved)" in path.read_text()
    assert "index.html: no rotation slider" in capsys.readouterr().err


def test_view_refuses_what_is_not_a_folder(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing")]) == 1
    assert "no such result folder" in capsys.readouterr().err
    assert main(["view", str(tmp_path), "--frames", "-1"]) == 1


# ---------------------------------------------------------------- the sweep


def test_capture_sweep_is_the_image_based_view_of_each_rotation(outputs):
    """Frame k of the sweep is relight.render.image_based_view (an independent path: its own weights call per
    sweep, its own ray cast per frame) of the environment turned by 360 k / K degrees, tone-mapped at the
    sweep's exposure: within 1 of 255 (float32 summation order)."""
    from relight.envmap import bundled_envmap_path, load_envmap, rotation_matrix
    from relight.image import to_uint8, tonemap
    from relight.io import load_texel_capture
    from relight.render import image_based_view
    from relight.view import capture_sweep, preview_envmap

    capture, surface, mesh, _ = load_texel_capture(outputs / "cap")
    env = load_envmap(bundled_envmap_path())
    sweep = capture_sweep(capture, surface, mesh, capture.cameras[0], env, frames=4, size=SIZE)
    assert sweep.frames.shape == (4, SIZE, SIZE, 3) and np.allclose(sweep.angles_deg, [0, 90, 180, 270])
    rots = np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                     for a in sweep.angles_deg])
    ref = image_based_view(capture, surface, mesh, capture.cameras[0], preview_envmap(env), rotations=rots)
    want = to_uint8(tonemap(ref, exposure=sweep.exposure, curve="filmic"))
    assert np.max(np.abs(want.astype(int) - sweep.frames.astype(int))) <= 1
    assert np.mean(np.abs(np.diff(sweep.frames.astype(float), axis=0))) > 1.0  # the light moves


def test_preview_envmap_keeps_the_integral():
    """Area-averaging by whole blocks, weighted by the rows' solid angles, keeps the map's integral over the
    sphere (float32 rounding) and a constant map constant."""
    from relight.envmap import EnvMap, envmap_integral
    from relight.view import preview_envmap

    rng = np.random.default_rng(0)
    env = EnvMap(rng.gamma(0.5, 2.0, size=(64, 128, 3)).astype(np.float32))
    small = preview_envmap(env, width=32)
    assert small.radiance.shape == (16, 32, 3)
    np.testing.assert_allclose(np.asarray(envmap_integral(small)), np.asarray(envmap_integral(env)), rtol=2e-3)
    flat = preview_envmap(EnvMap(np.full((64, 128, 3), 0.7, np.float32)), width=32)
    np.testing.assert_allclose(np.asarray(flat.radiance), 0.7, rtol=1e-6)
    assert preview_envmap(env, width=256) is env  # already small enough


# ---------------------------------------------------------------- report.md


def test_markdown_renders_the_report_subset_and_escapes_the_rest():
    from relight.view import markdown_html

    md = ("# Title\n\nSome *emph*, **bold**, `a<b>` and a [link](https://example.org) and "
          "[bad](javascript:alert(1)); snake_case_name and 2 * 3 * 4.\n\n"
          "| map | median |\n| --- | ---: |\n| albedo | 1.2% |\n| <script>x</script> | a \\| b |\n\n"
          "- one\n- two\n  continued\n\n1. first\n2. second\n\n```\ncode <x>\n```\n")
    out = markdown_html(md, heading_offset=1)
    assert "<h2>Title</h2>" in out
    assert "<em>emph</em>" in out and "<strong>bold</strong>" in out and "<code>a&lt;b&gt;</code>" in out
    assert '<a href="https://example.org">link</a>' in out and "javascript:" not in out.split("bad")[0]
    assert 'href="javascript' not in out and "snake_case_name" in out and "2 * 3 * 4" in out
    assert "<thead><tr><th>map</th><th>median</th></tr></thead>" in out and "<td>1.2%</td>" in out
    assert "<script>" not in out and "&lt;script&gt;" in out and "<td>a | b</td>" in out
    assert "<ul><li>one</li><li>two continued</li></ul>" in out and "<ol><li>first</li><li>second</li></ol>" in out
    assert "<pre><code>code &lt;x&gt;</code></pre>" in out


def test_view_constants_are_the_librarys():
    from relight import view
    from relight.cli import view as view_cli

    assert (view_cli.FRAMES, view_cli.SIZE) == (view.DEFAULT_FRAMES, view.DEFAULT_SIZE)


def test_relight_view_envmap_reaches_the_3d_view(outputs, tmp_path, monkeypatch, capsys):
    """`relight view MAPS --envmap FILE` lights the 3D view by FILE too, not only the slider's sweep (the view's
    environment is handed to relight.view._page3d.view3d_html; without --envmap, None: the folder's own)."""
    import shutil

    import relight.view._page3d as page3d
    from relight.envmap import bundled_envmap_path

    seen = []
    monkeypatch.setattr(page3d, "view3d_html", lambda *a, **k: (seen.append(a[-1]), ("", ""))[1])
    folder = tmp_path / "maps"
    shutil.copytree(outputs / "maps", folder)
    env = str(bundled_envmap_path())
    for argv in ([], ["--envmap", env]):
        assert main(["view", str(folder), "--frames", "2", "--size", "16", "-qq", *argv]) == 0
    assert seen == [None, env]
