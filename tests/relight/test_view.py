"""The results viewer (``relight view``, ``relight.view``; issue 18): every command's output folder holds an
``index.html`` that loads in a real browser (headless Chromium) with no console error and whose rotation slider
changes the displayed image; the page is self-contained (``data:`` images only, no network) and listed in the
folder's manifest; ``relight view`` rewrites it with a finer sweep; the sweep is the project's image-based
relighting of each rotation; report.md is rendered with its markup escaped.

One tiny output per command, made once for the module: simulate (the head at 12 x 12 texels under a 42-light
dome, one 32 x 32 camera), fit (Gauss-Newton), render of the map set and a 4-frame turntable of the capture;
the demo is the run's one (conftest's demo_output, 32 x 32 texels, 1 camera), whose physics test_cli.py
tests and whose page is tested here.
The browser tests skip, saying why, where Chromium is absent (``.ci/run`` installs it)."""

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


def _selftest(page: Path, profile: Path) -> tuple[dict, list[str]]:
    """Open ``page#selftest`` in headless Chromium; (the page's self-test result, the console lines). Tried
    twice: on a loaded machine a first start of a fresh profile can end its virtual time before the page's
    load event."""
    for attempt in range(2):
        out = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                              f"--user-data-dir={profile}-{attempt}", "--virtual-time-budget=30000",
                              "--enable-logging=stderr", "--v=0", "--dump-dom", page.resolve().as_uri() + "#selftest"],
                             capture_output=True, text=True, timeout=180)
        m = re.search(r'<pre id="selftest-result">(.*?)</pre>', out.stdout, re.S)
        if m:
            break
    assert m, f"no self-test result in the DOM (rc {out.returncode}): {out.stderr[-1500:]}"
    console = [line for line in out.stderr.splitlines() if ":CONSOLE" in line]
    return json.loads(html.unescape(m.group(1))), console


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
