"""The ``relight`` command as a researcher meets it (issue 18): ``--version``, a ``--help`` that imports no
JAX, progress bars with one bar and one total per phase and no ETA while compiling, ``-q`` / ``-qq``, fit's
``--solver`` (the old ``--method`` refused), previews enlarged past 256 px (``truth/`` included), and
fit's report: every error over all seen texels and over the unflagged ones, with the counts."""

import io
import json
import os
import re
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from relight.cli import COMMANDS, build_parser, main
from relight.cli._common import PREVIEW_MIN_PX, Bar, upscale_nearest

from ._cli_runs import small_index

ROOT = Path(__file__).resolve().parents[2]
RES = 12  # texel grid of the end-to-end capture (about 60 seen texels under the 42-light dome)


# ------------------------------------------------------------------ start-up


def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"relight {version('lightstage-relight')}"


# relight/__init__.py loads its subpackages on first use (PEP 562), so this check imports the real package:
# the dispatcher must import no command module, and so no JAX, to print the top-level help or the version.
_NO_JAX = """
import sys
sys.path.insert(0, {root!r})
from relight.cli import main
for argv in {argv!r}:
    try:
        main(argv)
    except SystemExit as exc:
        assert exc.code == 0, exc.code
heavy = sorted(m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib", "stage", "brdf", {extra})
               or (m.startswith("relight.") and m.split(".")[1] != "cli"))
print("HEAVY", heavy)
"""


def _heavy_imports(argv, extra: str) -> str:
    out = subprocess.run([sys.executable, "-c", _NO_JAX.format(root=str(ROOT), argv=argv, extra=extra)],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_top_level_help_and_version_import_no_jax():
    out = _heavy_imports([["--help"], ["--version"]], '"numpy"')
    assert "HEAVY []" in out, out[-400:]
    assert "usage: relight" in out and "simulate" in out and "info" in out
    assert "relight.cli.fit" not in out


def test_command_help_imports_no_jax():
    """Every command builds its parser from relight.cli._common alone (NumPy allowed): simulate's names its
    --subsurface presets without reading skin_bssrdf, view's its defaults without relight.view."""
    argv = [[name, "--help"] for name, _ in COMMANDS]
    out = _heavy_imports(argv, '"jax", "equinox", "skin_bssrdf"')
    assert "HEAVY []" in out, out[-600:]
    for name, _ in COMMANDS:
        assert f"usage: relight {name}" in out, name
    assert "skin1" in out and "--no-index" in out


def test_simulate_and_view_start_in_well_under_a_second():
    """`relight simulate --help` used to import JAX at module load (about 2 s); now it takes what the others
    take. Measured in a subprocess, best of 2 (the machine's load moves one run)."""
    code = ("import sys, time; sys.path.insert(0, {root!r}); t = time.perf_counter(); from relight.cli import main\n"
            "try:\n    main([{cmd!r}, '--help'])\nexcept SystemExit:\n    pass\n"
            "print('T', time.perf_counter() - t)")
    for cmd in ("simulate", "view"):
        best = min(float(re.search(r"T ([0-9.]+)", subprocess.run(
            [sys.executable, "-c", code.format(root=str(ROOT), cmd=cmd)], capture_output=True, text=True,
            timeout=60, cwd=ROOT).stdout).group(1)) for _ in range(2))
        assert best < 1.0, (cmd, best)


def test_parser_constants_are_the_librarys():
    """The choices spelled in the CLI so that a parser needs no JAX are the library's own."""
    import relight
    import stage
    from relight.cli import _common, fit

    assert fit.METHODS == tuple(relight.SOLVERS)
    assert fit.FIT_MODELS == (*relight.MODELS[:relight.MODELS.index("subsurface")], "auto")
    assert _common.RIG_UNITS == tuple(stage.POSITION_UNITS)
    assert _common.RIG_AXES == tuple(stage.AXES)
    from relight.cli import simulate
    from relight.image import PREVIEW_MIN_PX as LIBRARY_MIN_PX

    assert simulate._PRESET_NAMES == _common.SUBSURFACE_PRESETS
    assert PREVIEW_MIN_PX == LIBRARY_MIN_PX
    # The stated size limits: the largest texel grid (a label map's) and image (a camera's).
    from relight.cli._flags import LIMITS
    from relight.io._regions import MAX_LABEL_PIXELS

    assert LIMITS["--resolution"] ** 2 == MAX_LABEL_PIXELS
    assert LIMITS["--image-size"] ** 2 == stage.MAX_CAMERA_PIXELS


def test_the_dispatcher_help_lines_are_the_commands_own():
    """relight --help lists COMMANDS' lines without importing the modules: they must be the modules' own."""
    full = build_parser(commands="all")
    sub = next(a for a in full._actions if a.dest == "command")
    own = {a.dest: a.help for a in sub._choices_actions}
    assert own == dict(COMMANDS)
    assert list(own) == [name for name, _ in COMMANDS]


def test_command_help_builds_only_that_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["fit", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "--solver" in text and "least-squares solver" in text
    assert "--method" not in text


def test_demo_help_has_a_description(capsys):
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = capsys.readouterr().out
    assert "Run the whole pipeline on built-in data" in text and "-qq" in text


# ------------------------------------------------------------------ progress bars


def _frames(stream: io.StringIO) -> list[str]:
    """Every bar line tqdm drew (carriage returns and cursor moves split)."""
    text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "\n", stream.getvalue())
    return [f.strip() for f in re.split(r"[\r\n]", text) if f.strip()]


def _eta(frame: str) -> bool:
    """A frame showing an elapsed<remaining estimate or a rate."""
    return bool(re.search(r"<\d|it/s|s/it", frame))


def _auto_fit_stream(b, totals: dict) -> None:
    """What a --model auto fit reports: each rung opened at 0, then half of each per block over two blocks,
    interleaved, then a phase without a total ("merge") to 3."""
    for name, total in totals.items():
        b(name, 0, total)
    for block in (1, 2):
        for name, total in totals.items():
            b(name, total * block // 2, total)
    b("merge", 0, None)
    b("merge", 3, None)


def test_bar_has_one_bar_per_phase_each_with_its_total():
    """A --model auto fit's stream: rungs interleaved over two blocks, each rung its own total, a phase
    without a total; every phase gets its own bar with its own total, the command's placeholder bar
    (nothing counted) gives way to the first phase, and the counts end where the stream ends."""
    stream = io.StringIO()
    b = Bar(110, "fit (texels)", quiet=False, file=stream, live=True, mininterval=0, miniters=1)
    totals = {"fit lambert": 10, "fit ggx": 66, "fit blinn_phong": 34}
    _auto_fit_stream(b, totals)
    assert set(b._bars) == {*totals, "merge"}  # the placeholder is gone, one bar per phase
    for name, total in totals.items():
        assert b._bars[name].total == total and b._bars[name].n == total
    assert b._bars["merge"].total is None and b._bars["merge"].n == 3
    b.close()
    frames = _frames(stream)
    for name, total in totals.items():
        mine = [f for f in frames if f.startswith(name + ":")]
        assert any(f"{total}/{total}" in f for f in mine), (name, mine)
        assert not any(re.search(rf"\d+/(?!{total}\b)\d+", f) for f in mine), (name, mine)  # no other total


def test_bar_shows_no_eta_before_the_first_unit_and_times_from_it():
    """Before a phase's first finished unit (JAX compiling) the bar says "compiling" and shows no rate or ETA;
    at the first unit the clock restarts, so the compile time never enters the rate (tqdm's rate is
    (n - initial) / elapsed): the ETA is that of the chunks after the first."""
    stream = io.StringIO()
    b = Bar(None, "simulate", quiet=False, file=stream, live=True, mininterval=0, miniters=1)
    b("simulate", 0, 1496)
    b("simulate", 0, 1496)
    waiting = _frames(stream)
    assert waiting and all("compiling" in f and not _eta(f) for f in waiting), waiting
    before = time.time()
    b("simulate", 1, 1496)
    bar_ = b._bars["simulate"]
    assert bar_.initial == 1 and bar_.n == 1 and bar_.start_t >= before - 1e-3
    b("simulate", 2, 1496)
    b("simulate", 3, 1496)
    after = _frames(stream)[len(waiting):]
    assert after and not any("compiling" in f for f in after)
    assert any(_eta(f) for f in after), after
    b.close()


def test_a_log_gets_one_plain_line_per_phase():
    """Where nothing can be redrawn (a file, a pipe: ``live`` defaults to the stream's isatty), each phase prints
    one line when its count reaches its total, or at the end, with its seconds: no cursor codes, no stacked
    bars, no rate extrapolated from a phase's first seconds (issue 29: `fit lambert 61/5356 [02:13<1:11:20]` in
    a log, for a phase that ended seconds later)."""
    stream = io.StringIO()
    with Bar(110, "fit (texels)", quiet=False, file=stream) as b:  # StringIO is no terminal: line mode
        _auto_fit_stream(b, {"fit lambert": 10, "fit ggx": 66})
        assert stream.getvalue().count("\n") == 2  # the two rungs, as each completed; merge has no total yet
    lines = stream.getvalue().splitlines()
    assert "\x1b" not in stream.getvalue() and "\r" not in stream.getvalue()
    assert [line.split(":")[0] for line in lines] == ["fit lambert", "fit ggx", "merge"], lines
    assert re.fullmatch(r"fit lambert: 10/10 in \d+\.\d s( \(\d+\.\d s before the first\))?", lines[0]), lines
    assert re.fullmatch(r"merge: 3 in \d+\.\d s.*", lines[2]) and not any(_eta(f) for f in lines), lines
    # A phase without a total prints at the close, with the time to its last unit, not to the close.
    stream = io.StringIO()
    with Bar(None, "fit", quiet=False, file=stream) as b:
        b("fit ggx (more steps)", 0, None)
        b("fit ggx (more steps)", 5, None)
        time.sleep(0.3)
    assert re.fullmatch(r"fit ggx \(more steps\): 5 in 0\.[01] s\n", stream.getvalue()), stream.getvalue()
    # A phase that starts again (done back to 0: a second pass) is a new count, the first one's line out first.
    stream = io.StringIO()
    with Bar(None, "fit", quiet=False, file=stream) as b:
        for n in (0, 4, 0, 2):
            b("fit ggx (more steps)", n, None)
    assert re.findall(r": (\d+) in", stream.getvalue()) == ["4", "2"], stream.getvalue()


def test_a_reading_phase_says_reading_and_quiet_draws_nothing():
    stream = io.StringIO()
    with Bar(None, "read mask", quiet=False, file=stream, waiting="reading", live=True, mininterval=0,
             miniters=1) as b:
        b("read mask", 0, 42)
    assert any("reading" in f and "compiling" not in f for f in _frames(stream))
    stream = io.StringIO()
    with Bar(10, "fit (texels)", quiet=1, file=stream) as b:
        for k in range(11):
            b("fit ggx", k, 10)
        b.update(0)
    assert stream.getvalue() == ""


# ------------------------------------------------------------------ --solver


def test_fit_method_is_refused(capsys):
    """``fit --method`` (the solver's old name, removed before the first release) is a usage error."""
    with pytest.raises(SystemExit) as exc:
        main(["fit", "somewhere", "--out", "elsewhere", "--method", "gn"])
    assert exc.value.code == 2
    assert "unrecognized arguments: --method" in capsys.readouterr().err


# ------------------------------------------------------------------ the report's errors


def _fake(rho_d, rho_s, alpha, model, normal, failed=None, observed=None):
    P = len(model)
    return SimpleNamespace(rho_d=np.asarray(rho_d, np.float64), rho_s=np.asarray(rho_s, np.float64),
                           alpha=np.asarray(alpha, np.float64), model=np.asarray(model),
                           normal=np.asarray(normal, np.float64),
                           failed=np.zeros(P, bool) if failed is None else np.asarray(failed),
                           observed=np.full(P, 20.0) if observed is None else np.asarray(observed, np.float64))


def test_errors_over_all_seen_and_unflagged_texels_with_counts():
    """Six texels, one unseen: known relative errors. Albedo: 1%, 1%, 10%, 10%, 40% on the five seen (the two
    10% and the 40% ones flagged); roughness only where fit and truth both have a lobe (the Lambert fit's
    placeholder 0.5 against a true 0.25 is a 100% error that must not count); normals in degrees."""
    from relight.fitting import truth_errors
    from relight.materials import GGX, LAMBERT

    P = 6
    t_rho = np.full((P, 3), 0.5)
    f_rho = t_rho * np.array([1.01, 1.01, 1.10, 1.10, 1.40, 3.0])[:, None]
    t_alpha = np.full((P, 2), 0.25)
    f_alpha = t_alpha * np.array([1.02, 1.02, 1.2, 1.2, 1.0, 1.0])[:, None]
    f_alpha[4] = 0.5  # the Lambert rung's placeholder
    f_model = np.array([GGX, GGX, GGX, GGX, LAMBERT, GGX])
    t_model = np.full(P, GGX)
    tilt = np.radians([0.0, 2.0, 4.0, 6.0, 8.0, 0.0])
    f_n = np.stack([np.sin(tilt), np.zeros(P), np.cos(tilt)], 1)
    t_n = np.tile([0.0, 0.0, 1.0], (P, 1))
    fitted = _fake(f_rho, np.full((P, 1), 0.028 * 1.5), f_alpha, f_model, f_n,
                   failed=np.array([False, False, True, True, True, False]),
                   observed=np.array([20, 20, 20, 20, 20, 0]))
    truth = _fake(t_rho, np.full((P, 1), 0.028), t_alpha, t_model, t_n)
    a = truth_errors(fitted, truth, normals=True)
    e = a["errors"]
    assert a["seen_samples"] == 5 and a["unflagged_samples"] == 2
    assert e["diffuse_albedo_rel"]["all_seen"]["samples"] == 5
    assert e["diffuse_albedo_rel"]["all_seen"]["median"] == pytest.approx(0.10, rel=1e-9)
    assert e["diffuse_albedo_rel"]["unflagged"] == pytest.approx({"samples": 2, "median": 0.01, "p95": 0.01})
    assert not any("_rel_error_" in k for k in a)  # no flat copies of the unflagged rows
    assert e["roughness_rel"]["all_seen"]["samples"] == 4  # the Lambert texel left out
    assert e["roughness_rel"]["all_seen"]["median"] == pytest.approx(0.11, rel=1e-9)  # of 2, 2, 20, 20%
    assert e["roughness_rel"]["unflagged"]["median"] == pytest.approx(0.02, rel=1e-9)
    assert e["specular_albedo_rel"]["all_seen"]["median"] == pytest.approx(0.5, rel=1e-6)
    assert e["normal_deg"]["all_seen"]["median"] == pytest.approx(4.0, abs=1e-6)
    assert e["normal_deg"]["unflagged"]["median"] == pytest.approx(1.0, abs=1e-6)
    assert "normal_deg" not in truth_errors(fitted, truth)["errors"]
    assert not any(k.startswith("mfp") for k in a["errors"])  # the truth does not scatter
    # seen=: the demo counts every texel a camera sees, observations or not (here the unseen sixth too).
    every = truth_errors(fitted, truth, seen=np.ones(P, bool))
    assert every["seen_samples"] == 6 and every["errors"]["diffuse_albedo_rel"]["all_seen"]["samples"] == 6


def test_upscale_nearest_keeps_texels_square():
    img = np.arange(48 * 40 * 3, dtype=np.uint8).reshape(48, 40, 3)
    big = upscale_nearest(img)
    k = -(-PREVIEW_MIN_PX // 40)
    assert big.shape == (48 * k, 40 * k, 3) and min(big.shape[:2]) >= PREVIEW_MIN_PX
    np.testing.assert_array_equal(big[::k, ::k], img)
    np.testing.assert_array_equal(big[k - 1::k, k - 1::k], img)
    assert upscale_nearest(np.zeros((300, 300))).shape == (300, 300)


# ------------------------------------------------------------------ end to end


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = tmp_path_factory.mktemp("ux")
    with small_index():
        assert main(["simulate", "--rig", "dome:42", "--resolution", str(RES), "--image-size", "24",
                     "--out", str(root / "cap"), "-qq"]) == 0
        assert main(["fit", str(root / "cap"), "--model", "ggx",
                     "--out", str(root / "maps"), "--solver", "gn", "--normals",
                     "-q"]) == 0
    return root


def test_fit_report_rows_say_over_which_texels(fitted):
    maps = fitted / "maps"
    report = json.loads((maps / "report.json").read_text())
    a = report["against_truth"]
    assert a["seen_samples"] == report["observed_samples"] > 20
    assert set(a["errors"]) == {"diffuse_albedo_rel", "specular_albedo_rel", "roughness_rel", "normal_deg"}
    for row in a["errors"].values():
        assert row["all_seen"]["samples"] >= row["unflagged"]["samples"]
    assert a["errors"]["diffuse_albedo_rel"]["unflagged"]["median"] < 0.05  # noise-free, 42 lights
    assert a["errors"]["normal_deg"]["all_seen"]["median"] < 5.0
    md = (maps / "report.md").read_text()
    assert f"over the {a['seen_samples']} seen texels" in md and "unflagged" in md
    assert "normal angle" in md and "specular albedo" in md
    # Three significant figures: no number in the report runs past 4 digits after the point.
    assert not re.search(r"\d\.\d{5,}", md), md
    settings = json.loads((maps / "settings.json").read_text())
    assert settings["flags"]["solver"] == "gn" and settings["resolved"]["fit_options"] == {"solver": "gn",
                                                                                           "model": "ggx",
                                                                                           "normals": True}
    assert "method" not in settings["flags"]


def test_texel_previews_are_enlarged_and_truth_has_them(fitted):
    from relight.io import read_maps, read_png

    for folder in (fitted / "maps", fitted / "cap" / "truth"):
        for name in ("albedo", "specular", "roughness"):
            img = np.asarray(read_png(folder / f"{name}.png"))
            assert min(img.shape[:2]) >= PREVIEW_MIN_PX and img.shape[0] % RES == 0, (folder, name, img.shape)
            k = img.shape[0] // RES
            np.testing.assert_array_equal(img[::k, ::k], img[k - 1::k, k - 1::k])  # whole-texel squares
    from relight.results import open_result_set

    read_maps(fitted / "cap" / "truth")
    truth_set = open_result_set(fitted / "cap" / "truth")  # the previews are part of the set: its manifest lists
    assert {"albedo.png", "specular.png", "roughness.png"} <= set(truth_set.files)
    truth_set.check()
    albedo = np.asarray(read_png(fitted / "cap" / "truth" / "albedo.png"), np.float64)
    assert albedo[..., 0].max() > 100  # the demo material's red albedo ~0.62, shown linear


def test_quiet_keeps_the_summary_and_qq_hides_it(fitted, tmp_path, capsys):
    assert main(["convert", str(fitted / "cap"), str(tmp_path / "a.zarr"), "-q"]) == 0
    out = capsys.readouterr()
    assert out.out.startswith("wrote store") and out.err == ""
    assert main(["convert", str(fitted / "cap"), str(tmp_path / "b.zarr"), "-qq"]) == 0
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_render_quiet_keeps_its_summary_and_qq_hides_it(fitted, tmp_path, capsys):
    """render's summary line goes through _common.summary like every command's: -q keeps it, -qq hides it."""
    assert main(["render", str(fitted / "maps"), "--out", str(tmp_path / "a"), "--no-index", "-q"]) == 0
    out = capsys.readouterr()
    assert out.out.startswith(f"wrote {tmp_path / 'a'}/ (1 frame(s), maps, method rig") and out.err == ""
    assert main(["render", str(fitted / "maps"), "--out", str(tmp_path / "b"), "--no-index", "-qq"]) == 0
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""


def test_a_closed_stdout_ends_quietly():
    """`relight info | head -1`: the reader is gone before the command writes (its end of the pipe closed
    first, so the write fails for certain); the command stops with 141 (128 + SIGPIPE) and no error text."""
    r, w = os.pipe()
    os.close(r)
    try:
        out = subprocess.run([sys.executable, "-c", "import sys; from relight.cli import main; "
                              "sys.exit(main(['--cache-dir', 'off', 'info']))"], stdout=w, stderr=subprocess.PIPE,
                             text=True, timeout=120, cwd=ROOT)
    finally:
        os.close(w)
    assert out.returncode == 141, out.stderr
    assert "Broken pipe" not in out.stderr and "Traceback" not in out.stderr
