"""The results viewer: one self-contained HTML page (``index.html``) for a result folder. It opens from
``file://`` in any browser, with no server and no network: every image is a ``data:`` URI, the CSS and the
script are inline.

What it shows, from what the folder holds: the relit subject with an environment-rotation slider (the
:class:`relight.view.Sweep` rows given), report.md (:func:`relight.view.markdown_html`), truth | fit | error of
the diffuse albedo, specular albedo and roughness where a truth map set is at hand (a demo's ``truth/`` and
``maps/``, a fit's capture's ``truth/``), a WebGL2 "3D view" of a map set on its mesh
(``relight/view/_page3d.py``), the texel-space maps, every other PNG (previews, charts, relit frames), and
settings.json.

Self-test (tests/relight/test_view.py): opened as ``index.html#selftest``, the page waits for its load
event (every embedded image decoded), moves the slider itself and writes ``<pre id="selftest-result">``
holding JSON: the errors a hook installed first in ``<head>`` caught (``window.onerror``, ``console.error``,
unhandled rejections, images that failed to load), the images and how many of them did not decode, the
number of sweeps and frames, a hash of the displayed image's ``src`` before and after the move, and the width
the first frame decoded to (``moved_width``, the new frame's, once it has loaded), and the 3D view's own
self-test (``view3d``: WebGL2, frame hashes, GL errors, the analytic sphere's pixels) where the page has one.
The result is written at once, not after a promise: a headless browser's virtual time does not wait for image
decoding.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
import stat
from pathlib import Path

import numpy as np

import stage

from ._markdown import markdown_html
from ._sweep import Sweep

__all__ = ["INDEX", "MAX_EMBEDDED_BYTES", "data_uri", "page_html", "write_index"]

# Whether a map set's page has the 3D view section (its environment precomputation costs seconds per process; the
# suite's tests of other pages turn it off, as they shorten the sweeps: tests/conftest.py).
VIEW3D = True
INDEX = "index.html"
# Images embedded besides the sweeps: at most this many bytes in all (a folder of large PNGs still gives a
# page that opens at once; what is left out is listed by name).
MAX_EMBEDDED_BYTES = 24 << 20
# A single PNG larger than this is linked, not embedded.
MAX_IMAGE_BYTES = 4 << 20
# report.md and settings.json larger than this are not shown (a command writes a few kB of each).
MAX_TEXT_BYTES = 1 << 20
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Texel-space maps shown in the maps section and the truth | fit | error table, in this order.
MAP_PREVIEWS = ("albedo", "specular", "roughness", "mean_free_path", "coverage", "normals", "normal")
# Folders never searched for images: the Mitsuba scene's textures (EXR copies) and a fit's resumable parts.
_SKIP_DIRS = {"mitsuba", ".parts", "views", "radiance", "mask"}

_NAMES = {"albedo": "diffuse albedo", "specular": "specular albedo", "roughness": "roughness",
          "mean_free_path": "mean free path", "coverage": "coverage", "normals": "normals", "normal": "normal"}


def data_uri(image: np.ndarray) -> str:
    """A ``data:image/png;base64,...`` URI of a uint8 image [H, W] or [H, W, 1|3|4]."""
    from PIL import Image

    a = np.asarray(image)
    if a.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got {a.dtype}")
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG", optimize=False, compress_level=6)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _read_inside(folder: Path, path: Path, limit: int, signature: bytes = b"") -> tuple[bytes | None, str]:
    """The one rule for what the page takes from the folder it shows: ``path``'s bytes if it is a regular file
    inside ``folder`` once links are followed, of at most ``limit`` bytes, starting with ``signature`` (what its
    name claims); else (None, why). A link to a file elsewhere (``/etc/passwd``), a device (``/dev/zero``) or a
    FIFO is never opened, so it can neither leak into the page nor exhaust memory nor block."""
    try:
        real = path.resolve(strict=True)
        if not real.is_relative_to(folder.resolve()):
            return None, "a link to outside the folder"
        st = os.stat(real)
        if not stat.S_ISREG(st.st_mode):
            return None, "not a regular file"
        if st.st_size > limit:
            return None, "too large for the page"
        with open(real, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as err:
        return None, f"unreadable ({err.strerror or type(err).__name__})"
    if len(data) > limit:
        return None, "too large for the page"
    if not data.startswith(signature):
        return None, "not the type its name says"
    return data, ""


def _esc(s) -> str:
    """Text (from a file, a flag, a file name, anything) as HTML character data or an attribute value. A file
    name that is not valid UTF-8 reaches Python with its bytes as lone surrogates (``os.fsdecode``), and JSON
    may hold lone surrogates too; they are shown as U+FFFD, so the page names the file as well as it can
    instead of failing to encode."""
    text = str(s).encode("utf-8", "surrogatepass").decode("utf-8", "replace")
    return html.escape(text, quote=True)


# JSON that goes inside a <script> element: the HTML parser ends the element at the first "</script", whatever
# the JavaScript around it, and "<!--" changes how it parses; U+2028 / U+2029 end a line in older JavaScript.
_SCRIPT_ESCAPES = {ord("<"): "\\u003c", ord(">"): "\\u003e", ord("&"): "\\u0026", 0x2028: "\\u2028",
                   0x2029: "\\u2029"}


def _script_json(value) -> str:
    """``value`` as a JavaScript literal that is safe inside a <script> element: JSON with ``<``, ``>``, ``&``
    and the two Unicode line separators written as \\u escapes (the same string to JSON.parse and to
    JavaScript; never markup)."""
    return json.dumps(value).translate(_SCRIPT_ESCAPES)


# ---------------------------------------------------------------- truth | fit | error


def _heat(x: np.ndarray, vmax: float, where: np.ndarray) -> np.ndarray:
    import matplotlib

    rgb = matplotlib.colormaps["magma"](np.clip(np.nan_to_num(x) / vmax, 0.0, 1.0))[..., :3]
    return np.round(np.where(where[..., None], rgb, 0.0) * 255).astype(np.uint8)


def _shown(x: np.ndarray) -> np.ndarray:
    """A texel map as its preview shows it: linear 0-1 clipped, sRGB-encoded, grey for one channel."""
    from ..image import to_uint8, tonemap

    x = np.asarray(x, np.float32)
    if x.ndim == 2:
        x = x[..., None]
    if x.shape[-1] == 1:
        x = np.repeat(x, 3, -1)
    return to_uint8(tonemap(x, exposure=0.0, curve="none"))


def _comparison(truth_dir: Path, fit_dir: Path, building: Path | None = None) -> tuple[list, str | None]:
    """Rows (name, truth, fit, error, scale) of uint8 images for the truth | fit | error table, or a note.
    ``building``: the result set being written (its manifest not there yet), whose map sets are read without one."""
    from ..image import upscale_nearest
    from ..io import read_maps

    try:
        truth, _ = read_maps(truth_dir, building=truth_dir == building)
        fit, _ = read_maps(fit_dir, building=fit_dir == building)
    except (OSError, ValueError) as err:
        return [], f"no truth | fit | error table: {err}"
    if truth.resolution != fit.resolution:
        return [], (f"no truth | fit | error table: the truth's texel grid {truth.resolution} is not the fit's "
                    f"{fit.resolution}")
    on = np.asarray(truth.coverage, bool) & np.asarray(fit.coverage, bool)
    rows = []
    for name, t, f, vmax in (("albedo", truth.albedo, fit.albedo, 0.1), ("specular", truth.specular, fit.specular, 0.5),
                             ("roughness", truth.alpha[..., :1], fit.alpha[..., :1], 0.5)):
        t64, f64 = np.asarray(t, np.float64), np.asarray(f, np.float64)
        rel = np.mean(np.abs(f64 - t64) / np.maximum(np.abs(t64), 1e-6), axis=-1)
        where = on & (np.max(t64, axis=-1) > 0)
        vals = rel[where]
        stat = "" if vals.size == 0 else (f"median {100 * np.median(vals):.3g}%, "
                                          f"p95 {100 * np.percentile(vals, 95):.3g}%")
        rows.append((_NAMES[name], upscale_nearest(_shown(t64)), upscale_nearest(_shown(f64)),
                     upscale_nearest(_heat(rel, vmax, where)), f"0-{100 * vmax:g}%", stat))
    return rows, None


def _truth_pair(folder: Path) -> tuple[Path | None, Path | None]:
    """(truth map set, fitted map set) this folder holds or records: a demo's truth/ and maps/, a fit's
    capture's truth/ (maps.json metadata.capture) and itself, a capture's truth/ alone."""
    from ..io import is_map_set

    if is_map_set(folder / "truth") and is_map_set(folder / "maps"):
        return folder / "truth", folder / "maps"
    if is_map_set(folder):
        try:
            meta = (stage.parse_json((folder / "maps.json").read_bytes(), "maps.json").get("metadata") or {})
        except (OSError, ValueError, AttributeError):
            meta = {}
        cap = meta.get("capture")
        if isinstance(cap, str) and cap and is_map_set(folder / cap / "truth"):
            return folder / cap / "truth", folder
        return None, folder
    if is_map_set(folder / "truth"):
        return folder / "truth", None
    return None, None


# ---------------------------------------------------------------- the page


_CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;background:#fafafa;color:#222}
header{background:#1f2430;color:#eee;padding:14px 24px}header h1{margin:0;font-size:20px}
header p{margin:4px 0 0;color:#aab}nav a{color:#9cf;margin-right:14px}
main{padding:8px 24px 40px;max-width:1400px}section{margin:22px 0}h2{border-bottom:1px solid #ddd;padding-bottom:4px}
.sweeps{display:flex;flex-wrap:wrap;gap:16px}.sweeps figure{margin:0}
.sweeps img{width:320px;image-rendering:auto;background:#000}
.grid{display:flex;flex-wrap:wrap;gap:14px}.grid figure{margin:0;max-width:340px}
.grid img{max-width:320px;max-height:320px;image-rendering:pixelated;border:1px solid #ccc;background:#000}
figcaption{font-size:12px;color:#555;word-break:break-all}
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}
th{background:#eee}.cmp img{width:200px;image-rendering:pixelated;display:block}
pre{background:#f0f0f0;padding:8px;overflow:auto;max-height:420px}.note{color:#a50;font-style:italic}
#controls{margin:8px 0}#rotation{width:420px;vertical-align:middle}
"""

# Installed first in <head>: every error of the page, wherever it comes from, is collected for the self-test.
_HOOK = """
window.__errors=[];
window.addEventListener('error',function(e){var t=e.target;
 if(t&&t!==window&&t.tagName){window.__errors.push('failed to load <'+t.tagName.toLowerCase()+'>');}
 else{window.__errors.push('error: '+(e.message||e));}},true);
window.addEventListener('unhandledrejection',function(e){window.__errors.push('rejection: '+e.reason);});
(function(){var ce=console.error;console.error=function(){window.__errors.push('console.error: '+
 Array.prototype.join.call(arguments,' '));return ce.apply(console,arguments);};})();
"""

_SCRIPT = """
(function(){
var S=window.SWEEPS||[];var slider=document.getElementById('rotation');var label=document.getElementById('angle');
function show(i){S.forEach(function(s,k){var n=s.frames.length;var j=Math.round(i*n/S[0].frames.length)%n;
 document.getElementById('sweep'+k).src=s.frames[j];});
 if(label){label.textContent=S[0].angles[i].toFixed(0)+'\\u00b0';}}
if(slider&&S.length){slider.addEventListener('input',function(){show(parseInt(slider.value,10));});show(0);}
function hash(s){var h=2166136261;for(var i=0;i<s.length;i++){h^=s.charCodeAt(i);h=Math.imul(h,16777619)>>>0;}
 return h.toString(16);}
function selftest(){var r={errors:window.__errors,sweeps:S.length,frames:S.length?S[0].frames.length:0};
 var imgs=Array.prototype.slice.call(document.images);
 r.images=imgs.length;r.broken=imgs.filter(function(m){return !(m.complete&&m.naturalWidth>0);}).length;
 var p=document.createElement('pre');p.id='selftest-result';
 var write=function(){p.textContent=JSON.stringify(r);};
 var img=document.getElementById('sweep0');
 if(img&&slider){r.width=img.naturalWidth;r.before=hash(img.src);
  img.addEventListener('load',function(){r.moved_width=img.naturalWidth;write();});
  slider.value=String(Math.floor(S[0].frames.length/2));slider.dispatchEvent(new Event('input'));
  r.after=hash(img.src);r.value=slider.value;}
 if(window.VIEW3D&&window.VIEW3D.selftest){r.view3d=window.VIEW3D.selftest();}
 write();document.body.appendChild(p);}
if(location.hash==='#selftest'){if(document.readyState==='complete'){selftest();}
 else{window.addEventListener('load',selftest);}}
})();
"""


def _images(folder: Path, shown: set[str]) -> list[Path]:
    """PNGs of the folder and its subfolders (two levels), not yet ``shown``, in path order. The walk prunes
    hidden folders and those that hold data, not pictures (a store's chunk folders can hold 10^5 files)."""
    out = []
    for top, dirs, files in os.walk(folder):
        depth = len(Path(top).relative_to(folder).parts)
        dirs[:] = sorted(d for d in dirs if depth < 2 and d not in _SKIP_DIRS and not d.startswith("."))
        for f in sorted(files):
            p = Path(top) / f
            if f.lower().endswith(".png") and p.relative_to(folder).as_posix() not in shown:
                out.append(p)
    return sorted(out, key=lambda p: p.relative_to(folder).as_posix())


def _figure(uri: str, caption: str, title: str = "") -> str:
    t = f' title="{_esc(title)}"' if title else ""
    return f'<figure><img src="{uri}" alt="{_esc(caption)}"{t}><figcaption>{_esc(caption)}</figcaption></figure>'


def _relit(sweeps: list[Sweep], note: str | None) -> tuple[str, str]:
    """The slider section's HTML and the script line that holds its frames."""
    if not sweeps:
        return f'<p class="note">{_esc(note or "no rotation slider for this folder")}</p>', ""
    k = len(sweeps[0].frames)
    figs = "".join(f'<figure><img id="sweep{i}" class="sweep" src="{data_uri(s.frames[0])}" '
                   f'alt="{_esc(s.label)}"><figcaption>{_esc(s.label)}</figcaption></figure>'
                   for i, s in enumerate(sweeps))
    exp = [f"{s.exposure:+.2f} EV" for s in sweeps if np.isfinite(s.exposure)]
    controls = (f'<div id="controls"><label for="rotation">environment rotation about +y </label>'
                f'<input type="range" id="rotation" min="0" max="{k - 1}" step="1" value="0"> '
                f'<span id="angle">0°</span> <span class="note">({k} rotations'
                f'{", exposure " + ", ".join(exp) if exp else ""})</span></div>')
    data = [{"label": s.label, "angles": [float(a) for a in s.angles_deg], "frames": [data_uri(f) for f in s.frames]}
            for s in sweeps]
    return controls + f'<div class="sweeps">{figs}</div>', "window.SWEEPS=" + _script_json(data) + ";"


def _comparison_html(folder: Path, truth_dir: Path, fit_dir: Path, building: bool = False) -> str:
    """The truth | fit | error section's HTML (or a note saying why there is none); ``building``: ``folder`` is
    a result set still being written (:func:`page_html`'s ``location``)."""
    rows, why = _comparison(truth_dir, fit_dir, folder if building else None)
    if not rows:
        return f'<p class="note">{_esc(why)}</p>'
    cells = "".join(f"<tr><th>{_esc(n)}<br><small>{_esc(st)}</small></th><td><img src='{data_uri(t)}'></td>"
                    f"<td><img src='{data_uri(f)}'></td><td><img src='{data_uri(e)}'><small>relative error, "
                    f"{_esc(sc)}</small></td></tr>" for n, t, f, e, sc, st in rows)
    return (f"<p>Texel space; truth <code>{_esc(os.path.relpath(truth_dir, folder))}</code>, fit "
            f"<code>{_esc(os.path.relpath(fit_dir, folder))}</code>; error |fit − truth| / truth (mean over "
            "channels) over texels both cover.</p><table class='cmp'><tr><th></th><th>truth</th><th>fit"
            f"</th><th>error</th></tr>{cells}</table>")


def _checked(sweeps) -> list[Sweep]:
    sweeps = list(sweeps)
    for s in sweeps:
        if not isinstance(s, Sweep) or s.frames.ndim != 4 or len(s.frames) != len(s.angles_deg) or not len(s.frames):
            raise ValueError("sweeps must be relight.view.Sweep rows with frames [K, H, W, 3] and K angles")
    return sweeps


def _read_settings(folder: Path) -> dict:
    data, _ = _read_inside(folder, folder / "settings.json", MAX_TEXT_BYTES)
    try:
        doc = stage.parse_json(data, "settings.json") if data is not None else {}
    except ValueError:
        return {}
    return doc if isinstance(doc, dict) else {}


def _gallery(folder: Path, embed) -> tuple[list[str], list[str]]:
    """Figures of the texel-space map previews (the folder's, maps/'s, truth/'s) and of every other PNG;
    ``embed(path)`` gives a file's data URI or None (left out)."""
    maps, shown = [], set()
    for sub in ("", "maps/", "truth/"):
        for name in MAP_PREVIEWS:
            p = folder / f"{sub}{name}.png"
            if p.is_file():
                uri = embed(p)
                shown.add(f"{sub}{name}.png")
                if uri:
                    maps.append(_figure(uri, f"{sub}{name}.png — {_NAMES[name]}"))
    others = []
    for p in _images(folder, shown):
        uri = embed(p)
        if uri:
            others.append(_figure(uri, p.relative_to(folder).as_posix()))
    return maps, others


def page_html(folder: str | os.PathLike, sweeps=(), note: str | None = None, title: str | None = None,
              location: str | os.PathLike | None = None, envmap: str | os.PathLike | None = None) -> str:
    """The viewer page of ``folder`` (see the module docstring) as an HTML string: ``sweeps``
    (:class:`Sweep` rows sharing one slider; their angles are the first's), ``note`` (why there is no slider,
    shown in its place), ``title`` (default: the folder's name and the command that wrote it), ``location``
    (the folder the page describes, when it is written into a result set still being built elsewhere),
    ``envmap`` (the 3D view's environment; default the one settings.json records, else the bundled map)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such result folder")
    sweeps = _checked(sweeps)
    settings = _read_settings(folder)
    command = settings.get("command")
    where = Path(location) if location is not None else folder
    title = title or f"{where.resolve().name}" + (f" — {command}" if command else "")
    budget = [MAX_EMBEDDED_BYTES]
    left_out: list[str] = []

    def embed(path: Path) -> str | None:
        data, why = _read_inside(folder, path, min(MAX_IMAGE_BYTES, budget[0]), _PNG_SIGNATURE)
        if data is None:
            left_out.append(f"{path.relative_to(folder).as_posix()} ({why})")
            return None
        budget[0] -= len(data)
        return "data:image/png;base64," + base64.b64encode(data).decode("ascii")

    body, nav = [], []

    def section(key: str, heading: str, content: str) -> None:
        nav.append(f'<a href="#{key}">{_esc(heading)}</a>')
        body.append(f'<section id="{key}"><h2>{_esc(heading)}</h2>\n{content}\n</section>')

    relit, script_data = _relit(sweeps, note)
    section("relit", "Relit", relit)

    report = folder / "report.md"
    if report.exists() or report.is_symlink():
        text, why = _read_inside(folder, report, MAX_TEXT_BYTES)
        section("report", "Report", markdown_html(text.decode("utf-8", errors="replace"), heading_offset=2)
                if text is not None else f'<p class="note">report.md not shown: {_esc(why)}</p>')

    truth_dir, fit_dir = _truth_pair(folder)
    if truth_dir is not None and fit_dir is not None:
        section("truth", "Truth | fit | error", _comparison_html(folder, truth_dir, fit_dir, location is not None))
    script3d = ""
    if fit_dir is not None and VIEW3D:  # the maps on the mesh in WebGL2 (_page3d.py), at the sweeps' exposure
        from ._page3d import view3d_html

        exposure = next((s.exposure for s in sweeps if np.isfinite(s.exposure)), None)
        try:  # like a sweep's, its failure leaves a note, never a failed page
            html3d, script3d = view3d_html(folder, truth_dir, fit_dir, settings, exposure,
                                           folder if location is not None else None, envmap)
        except (ValueError, RuntimeError, OSError) as err:
            html3d, script3d = f'<p class="note">no 3D view: {_esc(err)}</p>', ""
        section("view3d", "3D view", html3d)

    maps, others = _gallery(folder, embed)
    if maps:
        section("maps", "Maps (texel space)", f'<div class="grid">{"".join(maps)}</div>')
    if others:
        section("images", "Images", f'<div class="grid">{"".join(others)}</div>')
    if left_out:
        body.append(f'<p class="note">Not embedded: {_esc(", ".join(left_out))}</p>')

    if settings:
        section("settings", "Settings", f"<pre>{_esc(json.dumps(settings, indent=2))}</pre>")

    sub = f"<p>{_esc(str(where.resolve()))}</p>"
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>\n"
            f"<script>{_HOOK}</script>\n<title>{_esc(title)}</title>\n"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>\n"
            f"<style>{_CSS}</style></head>\n<body><header><h1>{_esc(title)}</h1>{sub}<nav>{''.join(nav)}</nav>"
            f"</header><main>\n{''.join(body)}\n</main>\n<script>{script_data}</script>\n"
            + (f"<script>{script3d}</script>\n" if script3d else "") + f"<script>{_SCRIPT}</script>\n"
            "</body></html>\n")


def write_index(folder: str | os.PathLike, sweeps=(), note: str | None = None, title: str | None = None,
                location: str | os.PathLike | None = None, envmap: str | os.PathLike | None = None) -> Path:
    """Write :func:`page_html` to ``folder/index.html`` (atomically) and return its path."""
    from ..results import atomic_write_text

    folder = Path(folder)
    text = page_html(folder, sweeps, note, title, location, envmap)
    path = folder / INDEX
    atomic_write_text(path, text)
    return path
