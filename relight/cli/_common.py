"""Pieces the ``relight`` subcommands share: parsing ``--rig`` / ``--camera``,
the default ``--envmap``, the demo's ground-truth material, progress bars,
settings.json and previews. Library logic (reading captures and map sets,
rebuilding texel surfaces, relighting) lives in ``relight.io`` /
``relight.render``; command modules import only this module and the library."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

# JAX, stage, skin_bssrdf and relight.io are imported inside the functions that use them: a command's
# ``--help`` builds its parser from this module without them (tests/relight/test_cli_ux.py).

# stage.POSITION_UNITS and stage.AXES (the rig-file flags' choices), spelled here so that building a parser
# imports no JAX; tests/relight/test_cli_ux.py checks them against stage's.
RIG_UNITS = ("mm", "cm", "m", "directions")
RIG_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")


class CLIError(Exception):
    """A problem with the command line or its inputs: printed as
    ``relight <command>: error: <message>``, exit code 1."""


# A phase's bar before its first unit is done: JAX is tracing and compiling, so a rate or an ETA from the
# time spent so far would be one of hours (the first chunk pays the compile); it says "compiling" instead.
def _waiting_format(total, label: str) -> str:
    return f"{{desc}}: {{n_fmt}}{'/{total_fmt}' if total else ''} [{label}, {{elapsed}}]"


class Bar:
    """Progress bars (tqdm, on stderr) that are themselves the ``progress`` callback of every library call:
    ``progress(phase, done, total)`` (``stage.Progress``, the project's one protocol). Each phase gets its
    own bar with its own total (a rung of ``--model auto``, a subsurface pass), made when the phase first
    reports and kept while its count goes on (a phase may span several blocks, interleaved with others).
    Until a phase's first unit is done its bar reads ``compiling`` with no rate or ETA; from then on the
    rate counts only the time since, so the compile does not enter the ETA. A phase without a total shows
    its running count. ``quiet``: no bars at all. ``file``: the stream (default: tqdm's, stderr).
    ``waiting``: what a bar says before its first unit ("compiling"; a reading phase: "reading").
    ``tqdm_options``: passed to each tqdm (tests: ``mininterval=0, miniters=1`` to draw every report)."""

    def __init__(self, total, desc, quiet, leave=False, file=None, waiting: str = "compiling", **tqdm_options):
        self._quiet, self._leave, self._file, self._waiting = bool(quiet), leave, file, str(waiting)
        self._options = {"mininterval": 0.5, "dynamic_ncols": True, **tqdm_options}
        self._bars: dict[str, object] = {}
        self._running: dict[str, bool] = {}
        self._last = str(desc)
        self._open(self._last, total, 0)

    def _open(self, phase: str, total, done: int) -> None:
        from tqdm.auto import tqdm

        fmt = _waiting_format(total, self._waiting)
        kw = {} if self._file is None else {"file": self._file}
        self._bars[phase] = tqdm(total=total, desc=phase, unit="it", leave=self._leave, disable=self._quiet,
                                 initial=int(done), bar_format=None if done else fmt, **self._options, **kw)
        self._running[phase] = bool(done)

    def _start_rate(self, phase: str, done: int) -> None:
        """The first unit of ``phase`` is done: its bar shows rate and ETA, timed from now."""
        b = self._bars[phase]
        self._running[phase] = True
        b.bar_format = None
        if b.disable:
            b.n = done
            return
        b.reset(total=b.total)  # the clock and the smoothed rate start now
        b.n = b.last_print_n = b.initial = int(done)
        b.refresh()

    def __enter__(self) -> Bar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for b in self._bars.values():
            b.close()

    def update(self, n: int = 1) -> None:
        """Add ``n`` units to the bar that last reported (the bar's own phase at first)."""
        b = self._bars[self._last]
        self(self._last, b.n + int(n), b.total)

    def __call__(self, phase: str, done: int, total: int | None) -> None:
        phase, done = str(phase), int(done)
        self._last = phase
        b = self._bars.get(phase)
        if b is None:
            first = next(iter(self._bars))
            if len(self._bars) == 1 and self._bars[first].n == 0 and not self._running[first]:
                # The command's own placeholder bar (nothing counted yet) becomes this phase's.
                self._bars.pop(first).close()
                self._running.pop(first)
            self._open(phase, total, done)
            return
        if total != b.total:
            b.total = total
            if not self._running[phase]:
                b.bar_format = _waiting_format(total, self._waiting)
        if not self._running[phase] and done > 0:
            self._start_rate(phase, done)
            return
        b.update(done - b.n)


def bar(total, desc, quiet, leave=False, file=None, waiting: str = "compiling") -> Bar:
    """A :class:`Bar` opened on ``desc`` with ``total`` units until a library phase reports."""
    return Bar(total, desc, quiet, leave, file, waiting)


def summary(args) -> bool:
    """Whether the one-line summary prints: unless ``-qq`` (``--quiet`` alone hides the bars only)."""
    return int(getattr(args, "quiet", 0) or 0) < 2


def write_json(path, obj, indent: int = 2) -> None:
    """Reports and settings: ``relight.io``'s JSON writer (atomic; NaN and Inf refused), a failed write
    naming the file (a full disk as NoSpaceError)."""
    from ..io._json import write_json as _write_json

    with writing(path):
        _write_json(path, obj, indent)


def writing(path):
    """``relight.io._resultset.writing``: a context in which a failed write names ``path`` (a full disk as
    NoSpaceError)."""
    from ..io._resultset import writing as _writing

    return _writing(path)


def write_settings(out: Path, command: str, args, **resolved) -> None:
    """settings.json: the command, every flag as given/defaulted, and the resolved values."""
    flags = {k: v for k, v in vars(args).items() if k not in ("func", "command")}
    write_json(Path(out) / "settings.json", {"command": f"relight {command}", "flags": flags, "resolved": resolved})


def output_set(out: str | os.PathLike, command: str, quiet: int | bool = 0, keep=(), create: bool = True,
               unhashed=(), legacy=None):
    """The result set ``--out`` of ``relight <command>`` (``relight.io._resultset.result_set``): the folder
    locked (a second writer fails naming it), refused unless it is absent, empty or an earlier output of this
    command, built in a temporary sibling (the context's value) and swapped in whole with its manifest on
    success. Leftovers of killed runs are deleted (a warning on stderr says which). ``keep``, ``create``,
    ``unhashed`` and ``legacy`` (a folder this command wrote before manifests, which it may replace) are
    ``result_set``'s."""
    import sys

    from ..io._resultset import result_set

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: exists and is not a folder")

    def told(paths) -> None:
        if int(quiet or 0) < 2:
            print(f"relight {command}: warning: removed {len(paths)} leftover(s) of an interrupted run next to "
                  f"{out}: {', '.join(p.name for p in paths)}", file=sys.stderr)

    return result_set(out, command, command=f"relight {command}", keep=keep, create=create, unhashed=unhashed,
                      legacy=_own_or(command, legacy), on_stale=told)


def _own_or(command: str, legacy):
    """``legacy`` widened by what this command wrote before result-set manifests: a folder whose
    settings.json names ``relight <command>``."""
    def own(folder: Path) -> bool:
        import json

        try:
            doc = json.loads((folder / "settings.json").read_text())
        except (OSError, ValueError, UnicodeDecodeError):
            doc = None
        return (isinstance(doc, dict) and doc.get("command") == f"relight {command}") or bool(legacy and
                                                                                               legacy(folder))

    return own


def check_out(out: str | os.PathLike, command: str, keep=(), legacy=None) -> Path:
    """Refuse ``--out`` early (before any work) unless a later :func:`output_set` would take it: CLIError
    naming the folder and what it holds."""
    from ..io._resultset import ForeignFolderError, check_output_folder

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: exists and is not a folder")
    try:
        check_output_folder(out, command, keep=keep, legacy=_own_or(command, legacy))
    except ForeignFolderError as err:
        raise CLIError(f"--out {err}") from None
    return out


def _platform_error() -> str | None:
    """None when JAX's backend starts; else one line saying the requested platform is missing and what to do."""
    import jax

    try:
        jax.devices()
    except Exception as err:  # jax raises RuntimeError or a bare AssertionError (JAX_PLATFORMS=cuda on a CPU wheel)
        asked = os.environ.get("JAX_PLATFORMS") or os.environ.get("JAX_PLATFORM_NAME")
        why = f" ({err})" if str(err) else ""
        if asked:
            return (f"JAX_PLATFORMS={asked}: that platform is not available in this JAX install{why}; unset "
                    "JAX_PLATFORMS (or set it to cpu), or install the JAX build for it (pip install 'jax[cuda12]')")
        return f"JAX could not start a backend{why}; set JAX_PLATFORMS=cpu to use the CPU"
    return None


def check_numbers(args) -> None:
    """Refuse a non-finite float flag (nan, inf) before anything is computed or written: CLIError naming it."""
    import math

    for key, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CLIError(f"--{key.replace('_', '-')} {value}: must be a finite number")


def guarded(run):
    """``run(args)`` after the checks every command shares: a JAX backend that starts (else one line, exit 2)
    and finite float flags (else a CLIError)."""
    import functools
    import sys

    @functools.wraps(run)
    def wrapper(args) -> int:
        msg = _platform_error()
        if msg is not None:
            print(f"relight {getattr(args, 'command', '')}: error: {msg}", file=sys.stderr)
            return 2
        check_numbers(args)
        return run(args)

    return wrapper


# ------------------------------------------------------------------ the shared flags
# Flags several commands take, spelled, typed and explained once (docs/cli.md's table); each command adds the
# ones it uses, in its own order, with its own help text where the meaning differs.

# Smallest --image-size: a 'front' camera below 8 x 8 pixels frames nothing useful.
MIN_IMAGE_SIZE = 8


def add_out(p: argparse.ArgumentParser, help: str, default: str | None = None) -> None:
    """``--out``: the output folder (required unless the command has a ``default``)."""
    p.add_argument("--out", required=default is None, default=default, help=help)


def add_envmap(p: argparse.ArgumentParser, what: str = "lat-long environment map (.hdr/.exr/.pfm)") -> None:
    """``--envmap``: a map file, the bundled one when absent (:func:`envmap_path`)."""
    p.add_argument("--envmap", default=None, help=f"{what}; default: bundled")


def add_image_size(p: argparse.ArgumentParser, default: int = 256, what: str = "pixels of the 'front' camera") -> None:
    """``--image-size N``: N x N pixels (at least ``MIN_IMAGE_SIZE``, checked by :func:`at_least`)."""
    p.add_argument("--image-size", type=int, default=default, help=f"{what} (default: {default})")


def finish_parser(p: argparse.ArgumentParser, run) -> None:
    """What every working command ends with: ``--quiet`` and the function that runs it."""
    p.add_argument("-q", "--quiet", action="count", default=0,
                   help="no progress bars; twice (-qq): no summary line either (warnings and errors still show)")
    p.set_defaults(func=guarded(run))


def at_least(flag: str, value: int, minimum: int) -> None:
    """Refuse an integer flag below ``minimum`` (a CLIError naming the flag and the value)."""
    if value < minimum:
        raise CLIError(f"{flag} {value}: must be at least {minimum}")


# ------------------------------------------------------------------ rigs


def add_mesh_flags(p: argparse.ArgumentParser,
                   what: str = "mesh with UVs (.obj/.ply/.glb); default: the bundled head scan") -> None:
    """``--mesh`` with its placement: ``--units`` or ``--scale``, and ``--center``."""
    p.add_argument("--mesh", default=None, help=f"{what} (a copy of the head scan's file is placed like it)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--units", default=None, choices=("mm", "cm", "m"),
                   help="length unit of the mesh file (default: mm)")
    g.add_argument("--scale", type=float, default=None, help="millimetres per mesh-file unit (instead of --units)")
    p.add_argument("--center", default=None, action=argparse.BooleanOptionalAction,
                   help="move the mesh's bounding-box centre to the rig centre (default: no, except for the head scan)")


def mesh_from_args(args) -> dict:
    """The mesh spec (``relight.io.mesh_spec``) of ``--mesh/--units/--scale/--center``; CLIError on bad values."""
    from ..io import mesh_spec

    try:
        return mesh_spec(args.mesh, units=args.units, scale=args.scale, center=args.center)
    except ValueError as exc:
        raise CLIError(f"--mesh {args.mesh or 'head'}: {exc}") from None


def warn_mesh_size(command: str, mesh, rig) -> None:
    """Print ``relight.io.mesh_size_warning`` on stderr, if any."""
    import sys

    from ..io import mesh_size_warning

    msg = mesh_size_warning(mesh, rig)
    if msg:
        print(f"relight {command}: warning: {msg}", file=sys.stderr)


def add_rig_file_flags(p: argparse.ArgumentParser) -> None:
    """``--rig-units`` / ``--rig-up``: what a rig file does not record (a .npy or
    .txt position table: ``stage.load_rig_file``), or an override of what it does."""
    p.add_argument("--rig-units", default=None, choices=RIG_UNITS,
                   help="unit of the rig file's light positions (mm | cm | m | directions: distant lights); "
                        "needed for .npy/.txt rigs")
    p.add_argument("--rig-up", default=None, choices=(*RIG_AXES, "x", "y", "z"), metavar="AXIS",
                   help="the rig file's axis that points up, +x | -x | +y | -y | +z | -z (write a negative one as "
                        "--rig-up=-y); turned to the stage's +y; needed for .npy/.txt rigs")


def parse_rig(spec: str, units: str | None = None, up: str | None = None) -> tuple:
    """``lsx`` (ICT Light Stage X, 346 near-field lights), ``dome:N`` (N distant
    lights: a geodesic dome when N = 10 * 4^s + 2, else a Fibonacci sphere) or a
    rig file: a rig.json (a capture folder's rig: positions/directions +
    intensities), or any file ``stage.load_rig_file`` reads (.npy / .txt
    tables, the Light Stage X table), with ``units`` / ``up`` as stated."""
    import stage

    s = spec.strip()
    if s.lower() in ("lsx", "light_stage_x", "lightstage"):
        return stage.light_stage_x(), "ICT Light Stage X (346 lights, near field)"
    if s.lower().startswith("dome:"):
        try:
            n = int(s[5:])
        except ValueError:
            raise CLIError(f"--rig {spec}: dome:N needs an integer light count N") from None
        if n < 4:
            raise CLIError(f"--rig {spec}: a dome needs at least 4 lights")
        for sub in range(6):
            if 10 * 4**sub + 2 == n:
                return stage.geodesic_dome(sub), f"geodesic dome, {n} distant lights (subdivision {sub})"
        return stage.fibonacci_sphere(n), f"Fibonacci sphere, {n} distant lights"
    p = Path(s)
    if not p.exists():
        raise CLIError(f"--rig {spec}: not lsx, dome:N or an existing rig file")
    if p.is_dir():
        p = p / "rig.json"
    if units is not None or up is not None or p.suffix.lower() in (".npy", ".txt") or _is_lsx_table(p):
        stated = ", ".join(f"{k} {v}" for k, v in (("units", units), ("up", up)) if v is not None)
        return stage.load_rig_file(p, units=units, up=up), f"rig file {p}" + (f" ({stated})" if stated else "")
    return stage.load_rig(p), f"rig file {p}"


def _is_lsx_table(p: Path) -> bool:
    import stage

    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    try:
        doc = stage.read_json(p)
    except ValueError:
        return False
    return isinstance(doc, dict) and "positions_cm" in doc


# ------------------------------------------------------------------ cameras

FRONT_FOV_DEG = 11.0


def front_camera(mesh, size: int):
    """A telephoto camera on +z framing the mesh (for the bundled head: 1.3 m away, 11 degrees, as the demo)."""
    import stage

    v = np.asarray(mesh.vertices, np.float64)
    lo, hi = v.min(0), v.max(0)
    c = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    dist = 1.15 * max(half[0], half[1]) / np.tan(np.deg2rad(FRONT_FOV_DEG / 2)) + half[2]
    return stage.look_at((c[0], c[1], c[2] + dist), tuple(c), fov_deg=FRONT_FOV_DEG, width=size, height=size)


def front_ring(mesh, n: int, size: int) -> tuple:
    """1: :func:`front_camera`; n > 1: ``stage.camera_ring`` of n cameras at its
    distance over 80 degrees of azimuth around the front, aimed at the mesh's
    centre (the demo's and the photo round trip's several views)."""
    import stage

    front = front_camera(mesh, size)
    if n == 1:
        return (front,)
    v = np.asarray(mesh.vertices, np.float64)
    c = 0.5 * (v.min(0) + v.max(0))
    eye = -np.asarray(front.R, np.float64).T @ np.asarray(front.t, np.float64)
    return stage.camera_ring(n, float(np.hypot(eye[0], eye[2])), elevation_mm=float(c[1]), target=tuple(c),
                             fov_deg=FRONT_FOV_DEG, width=size, height=size, start_deg=-40.0, arc_deg=80.0)


def parse_cameras(spec: str | None, mesh, size: int, default=None) -> tuple:
    """``front`` (see :func:`front_camera`) or a camera file (``stage.load_cameras``:
    ``stage.save_cameras``'s, or a capture folder's ``cameras.json``, or a folder
    holding one)."""
    import stage

    if spec is None:
        if default is not None:
            return tuple(default)
        spec = "front"
    if spec == "front":
        return (front_camera(mesh, size),)
    p = Path(spec)
    if p.is_dir():
        p = p / "cameras.json"
    if not p.is_file():
        raise FileNotFoundError(f"--camera {spec}: not 'front' and no such cameras file")
    return stage.load_cameras(p)


# ------------------------------------------------------------------ previews


def auto_exposure(img: np.ndarray, coverage: np.ndarray | None = None) -> float:
    """The previews' one exposure rule, metered on the subject: :func:`relight.image.subject_exposure`
    (without a coverage, the pixels with positive luminance are the subject)."""
    from ..image._exposure import subject_exposure

    return subject_exposure(img, coverage)


# relight.image.PREVIEW_MIN_PX (texel-space previews are enlarged to at least this many pixels a side), spelled
# here so that building a parser imports no JAX; tests/relight/test_cli_ux.py checks it against the library's.
PREVIEW_MIN_PX = 256


def upscale_nearest(img: np.ndarray, min_px: int = PREVIEW_MIN_PX) -> np.ndarray:
    """``relight.image.upscale_nearest``: ``img`` [H, W, ...] enlarged nearest-neighbour by the smallest whole
    factor that makes its shorter side at least ``min_px``."""
    from ..image._preview import upscale_nearest as _upscale

    return _upscale(img, min_px)


def write_map_previews(folder: Path, albedo, specular, roughness) -> None:
    """albedo.png, specular.png, roughness.png of texel-space maps ([H, W, 3], [H, W, 1], [H, W, 1]; linear,
    0-1 shown as is), each enlarged by :func:`upscale_nearest`: ``relight fit``'s and ``truth/``'s."""
    for name, img in (("albedo", albedo), ("specular", specular), ("roughness", roughness)):
        write_preview(Path(folder) / f"{name}.png", img, exposure=0.0, curve="none", min_px=PREVIEW_MIN_PX)


def write_preview(path: Path, img: np.ndarray, exposure: float | None = None, curve: str = "filmic",
                  min_px: int = 0) -> None:
    """A tone-mapped PNG of linear ``img`` [H, W, C] (auto exposure when ``exposure`` is None); ``min_px``
    > 0: enlarged by :func:`upscale_nearest` (texel-space maps)."""
    from ..image._tonemap import to_uint8, tonemap
    from ..io._png import write_png

    img = np.asarray(img, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, -1)
    elif img.shape[-1] == 2:
        img = np.concatenate([img, np.zeros_like(img[..., :1])], -1)
    exposure = auto_exposure(img) if exposure is None else exposure
    png = to_uint8(tonemap(img, exposure=exposure, curve=curve))
    with writing(path):
        write_png(path, upscale_nearest(png, min_px) if min_px > 0 else png)


def add_index_flag(p: argparse.ArgumentParser) -> None:
    """``--no-index``: no index.html (the results viewer page, ``relight view``) in the output folder."""
    p.add_argument("--no-index", action="store_true",
                   help="do not write index.html, the results viewer (its rotation sweep costs about a second "
                        "at small sizes); `relight view OUT` writes it later")


# The sweep of the index.html a command writes into its output: fewer, smaller frames than `relight view`'s, so
# that the page adds little to the command's time (`relight view OUT` makes a finer one).
INDEX_FRAMES = 12
INDEX_SIZE = 128


def write_index_page(folder: Path, sweeps, command: str, quiet: int | bool = 0, committed: bool = False,
                     location: Path | None = None) -> tuple[Path, int]:
    """``folder/index.html``: ``relight.view.write_index`` with the rows and note ``sweeps()`` returns. A sweep
    that fails (ValueError, RuntimeError, OSError: an input that moved, a map it cannot read) leaves a page
    without a slider, saying why, and a warning on stderr: the page never fails the command. ``folder`` is a
    result set being built (the command's ``tmp``; ``location``: the folder it becomes), or, ``committed``, a
    finished folder: then it is locked while the page is written and, if it is a result set, its manifest
    lists the new index.html (``relight view``). Returns (the page's path, the number of sweeps)."""
    import sys

    from ..io._resultset import FolderLock, is_result_set

    folder = Path(folder)

    def make() -> tuple[Path, int]:
        from ..view import write_index

        try:
            rows, note = sweeps()
        except (ValueError, RuntimeError, OSError) as err:
            rows, note = [], f"no rotation slider: the sweep failed ({err})"
            if int(quiet or 0) < 2:
                print(f"relight {command}: warning: index.html: {note}", file=sys.stderr)
        return write_index(folder, rows, note, location=location), len(rows)

    if not committed:
        with writing(folder / "index.html"):
            return make()
    if not is_result_set(folder):
        with writing(folder / "index.html"):
            return make()
    with FolderLock(folder, f"relight {command}"):
        with writing(folder / "index.html"):
            path, n = make()
        _list_in_manifest(folder, path)
    return path, n


def _list_in_manifest(folder: Path, path: Path) -> None:
    """Put ``path`` (a file of the result set ``folder``, just written) into its manifest with its size and
    SHA-256; the other entries are kept as they are (they are not re-hashed: a page never vouches for files
    it did not write)."""
    import json

    from ..io._atomic import atomic_write_text
    from ..io._resultset import MANIFEST, _sha256

    doc = json.loads((folder / MANIFEST).read_text())
    doc.setdefault("files", {})[path.relative_to(folder).as_posix()] = {"size": path.stat().st_size,
                                                                        "sha256": _sha256(path)}
    atomic_write_text(folder / MANIFEST, json.dumps(doc, indent=1) + "\n")


def envmap_path(arg: str | None) -> Path:
    """``--envmap``: the given file, or the bundled map."""
    from ..envmap import bundled_envmap_path

    return Path(arg) if arg else bundled_envmap_path()


# ------------------------------------------------------------------ the demo's material


def demo_material(surface):
    """Ground-truth maps for ``relight simulate`` and ``relight demo``: skin-like
    diffuse albedo, F0 = 0.028 (skin's refractive index 1.4) and a roughness
    varying between 0.2 and 0.5 over the UVs. Returns float32
    ``(rho_d [P, 3], f0 [P, 1], alpha [P, 1])`` for ``brdf.lambert_ggx``."""
    import jax.numpy as jnp

    uv = np.asarray(surface.uv, np.float64)
    u, v = uv[:, 0], uv[:, 1]
    rho_d = np.stack([0.62 + 0.08 * np.sin(7 * u) * np.cos(5 * v),
                      0.42 + 0.06 * np.cos(6 * v + 1.0),
                      0.33 + 0.05 * np.sin(4 * u + 3 * v)], axis=1)
    f0 = np.full((len(u), 1), 0.028)
    alpha = 0.35 + 0.15 * np.sin(9 * u + 2.0) * np.sin(7 * v)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return f32(rho_d), f32(f0), f32(alpha[:, None])


# ------------------------------------------------------------------ subsurface scattering

# SUBSURFACE_PRESETS: Jensen et al. 2001's measured materials (skin_bssrdf.JENSEN2001), the names
# ``--subsurface`` takes: all but spectralon, whose sigma_a = 0 makes the diffuse mean free path infinite.
# Made on first use by the module's __getattr__ (PEP 562), so that importing this module needs no JAX.
# Energy fraction of the diffusion profile inside the operator's neighbour radius
# (skin_bssrdf.energy_radius): the 1% beyond it is dropped, as relight.render drops it.
SUBSURFACE_ENERGY = 0.99


def preset_mean_free_path(name: str) -> tuple[np.ndarray, float]:
    """(diffuse mean free path [3] in mm, eta) of a Jensen et al. 2001 material
    (``skin_bssrdf.JENSEN2001``): mfp = 1 / sigma_tr, sigma_tr = sqrt(3 sigma_a
    sigma_t') (Jensen & Buhler 2002 sec. 4; independent of eta), the diffuse
    mean free path Christensen & Burley 2015's ``dmfp`` fit takes. CLIError on
    an unknown name (listing the known ones)."""
    import jax.numpy as jnp

    import skin_bssrdf

    presets = _subsurface_presets()
    key = name.lower().replace(" ", "").replace("_", "")
    if key not in presets:
        if key in skin_bssrdf.JENSEN2001:
            raise CLIError(f"--subsurface {name}: sigma_a = 0, so its diffuse mean free path is infinite; "
                           f"choose one of {', '.join(presets)}")
        raise CLIError(f"--subsurface {name}: not a preset ({', '.join(presets)}) nor an existing "
                       "mean-free-path EXR")
    m = skin_bssrdf.JENSEN2001[key]
    _, mfp = skin_bssrdf.albedo_from_coefficients(jnp.asarray(m.sigma_a, jnp.float32),
                                                  jnp.asarray(m.sigma_s_prime, jnp.float32), m.eta)
    return np.asarray(mfp, np.float64), float(m.eta)


# ------------------------------------------------------------------ the persistent compilation cache

# The environment variable naming the cache folder ("" or "off": no cache); --cache-dir overrides it.
CACHE_ENV = "RELIGHT_CACHE_DIR"
# Programs that took at least this long to compile are written to the cache. 0: every program, the
# per-op ones of eager code included (a hit costs ~1 ms to read, a compile 10-50 ms; the solver's take
# seconds). Written before the first compile (main), so nothing compiled by a command escapes it.
CACHE_MIN_COMPILE_S = 0.0


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/relight/jax``, else ``~/.cache/relight/jax``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "relight" / "jax"


def cache_dir(flag: str | None) -> Path | None:
    """The persistent compilation cache folder: ``--cache-dir`` (``flag``), else ``$RELIGHT_CACHE_DIR``,
    else JAX's own setting (``JAX_COMPILATION_CACHE_DIR``) if any, else :func:`default_cache_dir`; None
    (no cache) when the chosen value is "", "off" or "none"."""
    spec = flag if flag is not None else os.environ.get(CACHE_ENV)
    if spec is None:
        import jax

        own = jax.config.jax_compilation_cache_dir
        return Path(own) if own else default_cache_dir()
    if spec.strip().lower() in ("", "off", "none"):
        return None
    return Path(spec).expanduser()


class compile_cache:
    """Context manager: JAX's persistent compilation cache in ``path`` (None: off) while a command runs
    (``jax_compilation_cache_dir``, ``jax_persistent_cache_min_compile_time_secs`` =
    CACHE_MIN_COMPILE_S, ``jax_persistent_cache_min_entry_size_bytes`` = -1: no size floor), then the
    process's previous settings back (an in-process ``main()`` leaves no global change behind).
    JAX opens its cache once per process, so a change of folder resets it
    (``compilation_cache.reset_cache``). A folder that cannot be made turns the cache off with a warning."""

    _KEYS = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes")

    def __init__(self, path: Path | None, command: str = ""):
        self.path, self.command = path, command

    def _set(self, values: dict) -> None:
        import jax
        from jax.experimental.compilation_cache import compilation_cache as cc

        changed = values["jax_compilation_cache_dir"] != jax.config.jax_compilation_cache_dir
        for k, v in values.items():
            jax.config.update(k, v)
        if changed:
            cc.reset_cache()

    def __enter__(self):
        import jax

        self._old = {k: getattr(jax.config, k) for k in self._KEYS}
        path = self.path
        if path is not None:
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                import sys

                print(f"relight {self.command}: warning: compilation cache {path}: {err}; running without it",
                      file=sys.stderr)
                path = None
        self._set({"jax_compilation_cache_dir": None if path is None else str(path),
                   "jax_persistent_cache_min_compile_time_secs": CACHE_MIN_COMPILE_S,
                   "jax_persistent_cache_min_entry_size_bytes": -1})
        return self

    def __exit__(self, *exc) -> None:
        self._set(self._old)


def _subsurface_presets() -> tuple[str, ...]:
    """SUBSURFACE_PRESETS (see its comment)."""
    import skin_bssrdf

    return tuple(sorted(k for k, m in skin_bssrdf.JENSEN2001.items() if min(m.sigma_a) > 0))


def __getattr__(name: str):
    # PEP 562: SUBSURFACE_PRESETS reads skin_bssrdf (and so JAX) only when asked for.
    if name == "SUBSURFACE_PRESETS":
        value = globals()["SUBSURFACE_PRESETS"] = _subsurface_presets()
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
