"""The results page's "3D view": the fitted (and truth) maps on the mesh, drawn by the page's own WebGL2
shader (``relight/data/viewer3d.js``, package data; no library, no network), with mouse orbit and zoom, an
environment-rotation slider, truth | fit | error switches and a map selector.

What the page embeds (one JSON object, ``window.VIEW3D_DATA``; arrays little-endian, base64):

* the mesh: positions (mm), normals, UVs (float32), triangle indices (uint32) and a per-vertex curvature
  (:func:`relight.view.vertex_curvature`), decimated to ``VIEW3D_MAX_TRIANGLES`` when larger
  (:func:`relight.view.decimate_mesh`);
* per map set (fit, and truth where the folder has one on the same mesh and grid), at the map resolution capped
  at ``VIEW3D_MAX_TEXTURE`` (block means above it): the diffuse albedo as an sRGB PNG, the world-space fitted
  normal as a PNG (0.5 n + 0.5), and float16 RGBA textures of (specular albedo F0, the lobe's alpha: alpha_x, or
  sqrt(alpha_x alpha_y) on the anisotropic rungs, model rung, coverage) and of the mean free path (mm) where a
  set has subsurface texels;
* the environment as ``relight.render.Fast`` prepares it (:func:`view3d_method`, on the map area-averaged to
  ``VIEW3D_ENV_WIDTH`` pixels across, :func:`view3d_envmap`): its order-2 SH coefficients (irradiance,
  Ramamoorthi & Hanrahan 2001), its GGX-prefiltered lat-long levels (split sum, Karis 2013) as one float16
  atlas, and the DFG table (float32);
* the exposure of the page's 2D sweeps (the same number, so the shaded view and the slider compare), the
  folder's camera as the first orbit pose, and the constant environment of the self-test's sphere.

Shading (the fragment shader is ``Fast``'s kernel without ambient occlusion, per pixel): Lambert rungs
rho_d / pi E(n) with E the SH irradiance of the rotated environment; GGX rungs the prefiltered environment at
the mirror direction times (F0 A + B) from the DFG table (anisotropic lobes as isotropic of alpha =
sqrt(alpha_x alpha_y)); Blinn-Phong rungs the prefiltered map times rho_s. The subsurface rung is approximated
locally: F_t(eta, cos_o) / pi * rho_d * T_avg * E_blur(n), the zero-mean-free-path limit of the renderer's
diffusion term (total reflectance rho_d), with the SH irradiance's bands damped by the heat kernel on the sphere,
exp(-l (l + 1) sigma^2 / 2), sigma = kappa * mfp per channel (kappa the mesh's curvature): light that diffuses a
distance mfp on a surface of curvature kappa averages the irradiance over normals sigma radians apart. No
shadows or interreflection (the renderer's ``Fast`` has ambient occlusion; here the sky is unoccluded).
"""

from __future__ import annotations

import base64
import functools
import json
import os
from importlib import resources
from pathlib import Path

import numpy as np

import skin_bssrdf
import stage

from ..envmap import EnvMap, bundled_envmap_path, load_envmap, sh_project
from ..materials import GGX_ANISO, SUBSURFACE
from ..render import Fast
from ..render._fast import mean_transmittance
from ._mesh3d import decimate_mesh, vertex_curvature
from ._page import _esc, _script_json, data_uri
from ._sweep import preview_envmap

__all__ = ["VIEW3D_ENV_WIDTH", "VIEW3D_MAX_TEXTURE", "VIEW3D_MAX_TRIANGLES", "view3d_data", "view3d_envmap",
           "view3d_html", "view3d_method"]

# The mesh the page draws: at most this many triangles (a 50k-triangle mesh is ~2 MB of base64).
VIEW3D_MAX_TRIANGLES = 50_000
# Texture side cap (texels): larger map sets are block-averaged down to it.
VIEW3D_MAX_TEXTURE = 1024
# The environment is area-averaged to this many pixels across before it is prefiltered (the sweeps' rule).
VIEW3D_ENV_WIDTH = 256
# Fast's prefiltered levels for the page: 7 roughness levels (Fast's default), the mirror level 64 rows (2.8
# degrees a texel), the others 32 rows; the DFG table 32 x 32 (Fast's default).
_FAST = {"levels": 7, "prefilter_rows": 64, "prefilter_samples": 64, "lut_size": 32}
# float16 holds at most 65504: the environment is scaled by a power of two (exact) that keeps it below this.
_HALF_MAX = 60000.0
# The error view shows |fit - truth| times this at first (a control sets 1, 4 or 16).
ERROR_GAIN = 4.0
# The self-test's sphere: uniform radiance of its constant environment.
SPHERE_RADIANCE = 1.0
_MAP_NAMES = {"fit": "fitted maps", "truth": "truth maps"}


def view3d_method() -> Fast:
    """The ``relight.render.Fast`` method whose precomputation (SH irradiance, GGX-prefiltered levels, DFG
    table) the 3D view embeds and whose kernel (without ambient occlusion) its shader evaluates: rendering
    with it (``relight.render.render_samples(..., method=view3d_method())``, no mesh) gives what the page
    draws, up to float16 storage of the environment."""
    return Fast(**_FAST)


def view3d_envmap(env: EnvMap) -> EnvMap:
    """The environment the 3D view prefilters: ``env`` area-averaged to at most ``VIEW3D_ENV_WIDTH`` pixels
    across (``relight.view.preview_envmap``, which keeps the integral)."""
    return preview_envmap(env, VIEW3D_ENV_WIDTH)


def _b64(a: np.ndarray, dtype) -> str:
    return base64.b64encode(np.ascontiguousarray(np.asarray(a), dtype=np.dtype(dtype).newbyteorder("<"))
                            .tobytes()).decode("ascii")


def _half_texture(x: np.ndarray) -> str:
    """[H, W, 4] float values as little-endian float16 base64 (non-finite -> 0, clipped to float16's range)."""
    x = np.where(np.isfinite(x), x, 0.0)
    return _b64(np.clip(x, -65504.0, 65504.0), np.float16)


def _shrink(x: np.ndarray, f: int, mode: str = "mean") -> np.ndarray:
    """[H, W, C] reduced by the whole factor ``f`` (edge-padded to a multiple): block means, or the block's
    first texel (``mode="first"``: labels)."""
    if f == 1:
        return x
    if mode == "first":
        return x[::f, ::f]
    h, w = x.shape[:2]
    pad = ((0, -h % f), (0, -w % f)) + ((0, 0),) * (x.ndim - 2)
    x = np.pad(x, pad, mode="edge")
    return x.reshape(x.shape[0] // f, f, x.shape[1] // f, f, *x.shape[2:]).mean(axis=(1, 3))


def _set_textures(textures, key: str, factor: int) -> tuple[dict, list[str]]:
    """One map set's textures: ({name: image id or base64}, the hidden <img> elements)."""
    from ..image import srgb_encode, to_uint8

    albedo = _shrink(np.clip(np.asarray(textures.albedo, np.float64), 0.0, 1.0), factor)
    normal = _shrink(np.asarray(textures.normal, np.float64), factor)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0)  # 0: no normal (the mesh's is used)
    alpha = np.asarray(textures.alpha, np.float64)
    coverage = np.where(textures.coverage, 1.0, np.where(textures.filled, 0.5, 0.0))
    alpha = np.maximum(alpha, 0.0)
    # Fast's lobe width: alpha_x, or sqrt(alpha_x alpha_y) on the anisotropic rungs (an isotropic lobe of that area)
    width = np.where(np.asarray(textures.model)[..., None] >= GGX_ANISO, np.sqrt(alpha[..., :1] * alpha[..., 1:2]),
                     alpha[..., :1])
    params = np.concatenate([np.asarray(textures.specular, np.float64), width, np.zeros_like(coverage)[..., None],
                             coverage[..., None]], axis=-1)
    params = _shrink(params, factor)
    params[..., 2] = _shrink(np.asarray(textures.model, np.float64)[..., None], factor, "first")[..., 0]
    ids = {"albedo": f"v3d-{key}-albedo", "normal": f"v3d-{key}-normal"}
    imgs = [f'<img id="{ids["albedo"]}" alt="" src="{data_uri(to_uint8(np.asarray(srgb_encode(albedo))))}">',
            f'<img id="{ids["normal"]}" alt="" src="{data_uri(to_uint8(0.5 * normal + 0.5))}">']
    out = {**ids, "params": _half_texture(params)}
    if np.any(np.asarray(textures.model) == SUBSURFACE):
        mfp = _shrink(np.asarray(textures.mfp, np.float64), factor)
        out["mfp"] = _half_texture(np.concatenate([mfp, np.ones_like(mfp[..., :1])], axis=-1))
    return out, imgs


def _environment(path: Path) -> dict:
    """The prefiltered environment of :func:`view3d_method` as the page holds it (module docstring), of the
    map file ``path``; kept for the process (:func:`_environment_cached`) while the file is unchanged."""
    st = path.stat()
    return _environment_cached(str(path.resolve()), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=4)
def _environment_cached(path: str, mtime_ns: int, size: int) -> dict:
    lighting = view3d_method().prepare(view3d_envmap(load_envmap(path)))
    levels = [np.asarray(lv, np.float64) for lv in lighting.levels]
    width = levels[0].shape[1]
    rects, y = [], 0
    for lv in levels:
        rects.append([0, y, lv.shape[1], lv.shape[0]])
        y += lv.shape[0]
    atlas = np.zeros((y, width, 4))
    for (x0, y0, w, h), lv in zip(rects, levels, strict=True):
        atlas[y0:y0 + h, x0:x0 + w, :3] = lv[..., :3]
    atlas[..., 3] = 1.0
    peak = float(np.max(atlas[..., :3]))
    shift = max(0, int(np.ceil(np.log2(peak / _HALF_MAX)))) if peak > _HALF_MAX else 0
    lut = np.asarray(lighting.lut, np.float32)
    return {"sh": np.asarray(lighting.sh, np.float64)[:, :3].reshape(-1).tolist(), "atlas": _half_texture(
            atlas * 2.0 ** -shift), "atlas_size": [width, y], "levels": rects, "scale": 2.0 ** shift,
            "lut": _b64(lut, np.float32), "lut_size": int(lut.shape[0]), "name": Path(path).name}


def _sphere_env() -> dict:
    """The self-test sphere's constant environment: its radiance L, SH coefficients (L sqrt(4 pi) in band 0,
    the projection of a constant map, 0 elsewhere) and float16 bits."""
    sh = np.zeros((9, 3))
    sh[0] = SPHERE_RADIANCE * np.sqrt(4.0 * np.pi)
    return {"radiance": SPHERE_RADIANCE, "sh": sh.reshape(-1).tolist(),
            "half": int(np.float16(SPHERE_RADIANCE).view(np.uint16))}


def _camera(info: dict, mesh: stage.Mesh) -> dict:
    """The first orbit pose: the map set's first camera (yaw, pitch, distance about the point of its axis
    nearest the mesh's centre, vertical field of view), else the front (+z) at 3 radii."""
    v = np.asarray(mesh.vertices, np.float64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    radius = float(np.max(np.linalg.norm(v - centre, axis=1)))
    pose = {"target": centre.tolist(), "radius": radius, "yaw": 0.0, "pitch": 0.0, "distance": 3.0 * radius,
            "fov_deg": 30.0, "from": "the front (+z)"}
    docs = (info.get("metadata") or {}).get("cameras") or []
    try:
        cam = stage.camera_from_dict(docs[0], "maps.json: metadata.cameras[0]")
    except (IndexError, KeyError, TypeError, ValueError):
        return pose
    if cam.orthographic:
        return pose
    R, t = np.asarray(cam.R, np.float64), np.asarray(cam.t, np.float64)
    eye, forward = -R.T @ t, R.T @ np.array([0.0, 0.0, 1.0])
    target = eye + max(float(np.dot(centre - eye, forward)), 1e-3 * radius) * forward
    d = eye - target
    dist = float(np.linalg.norm(d))
    if not np.isfinite(dist) or dist <= 0:
        return pose
    fov = float(np.degrees(2.0 * np.arctan(0.5 * cam.height / float(cam.K[1, 1]))))
    return {**pose, "target": target.tolist(), "distance": dist, "yaw": float(np.arctan2(d[0], d[2])),
            "pitch": float(np.arcsin(np.clip(d[1] / dist, -1.0, 1.0))), "fov_deg": fov,
            "from": f"camera {docs[0].get('name', '0')!s}"}


def _fallback_exposure(textures, path: Path) -> float:
    """Exposure metered (``relight.image.subject_exposure``) on the diffuse radiance rho_d / pi E(n) of the
    covered texels when the page has no sweep to take it from."""
    from ..envmap import sh_irradiance
    from ..image import subject_exposure

    on = np.asarray(textures.coverage, bool)
    if not np.any(on):
        return 0.0
    n = np.asarray(textures.normal, np.float32)[on]
    e = np.asarray(sh_irradiance(sh_project(view3d_envmap(load_envmap(path)), 2), n), np.float64)
    return subject_exposure((np.asarray(textures.albedo, np.float64)[on] / np.pi * e)[None])


def _same_mesh(a: dict, b: dict) -> bool:
    keys = ("bundled", "path", "scale", "center")
    return all(a.get(k) == b.get(k) for k in keys)


def view3d_html(folder: Path, truth_dir: Path | None, fit_dir: Path, settings: dict, exposure: float | None,
                building: Path | None = None, envmap: str | os.PathLike | None = None) -> tuple[str, str]:
    """The "3D view" section's HTML and its script (data, then ``viewer3d.js``), for the map set ``fit_dir``
    (and ``truth_dir`` when not None) of the page of ``folder``.

    Args:
        folder: the folder the page describes.
        truth_dir: the truth map set, or None.
        fit_dir: the fitted map set.
        settings: the folder's settings.json (the environment it records).
        exposure: the page's sweep exposure in stops (None: metered on the maps, :func:`_fallback_exposure`).
        building: a result set still being written (its map sets are read without their manifest).
        envmap: the environment (default: the one settings.json records, else the bundled map).

    Returns:
        (html, script); ``html`` is a note and ``script`` empty when the maps or their mesh cannot be read.
    """
    from ..io import read_maps, spec_mesh

    try:
        fit = read_maps(fit_dir, building=fit_dir == building)[0]
        info = fit.info
        mesh = spec_mesh(info.get("surface") or {}, str(fit_dir / "maps.json"))
    except (OSError, ValueError) as err:
        return f'<p class="note">no 3D view: {_esc(err)}</p>', ""
    notes, truth = [], None
    if truth_dir is not None:
        try:
            truth = read_maps(truth_dir, building=truth_dir == building)[0]
            tinfo = truth.info
        except (OSError, ValueError) as err:
            notes.append(f"no truth: {err}")
        else:
            if truth.resolution != fit.resolution or not _same_mesh(tinfo.get("surface") or {},
                                                                   info.get("surface") or {}):
                notes.append("no truth: the truth maps are on another mesh or texel grid")
                truth = None
    resolved = settings.get("resolved") if isinstance(settings.get("resolved"), dict) else {}
    spec = envmap or settings.get("envmap") or resolved.get("envmap")
    env_path = Path(spec) if spec else bundled_envmap_path()
    try:
        environment = _environment(env_path)
    except (OSError, ValueError) as err:
        return f'<p class="note">no 3D view: the environment map: {_esc(err)}</p>', ""
    n_faces = len(mesh.faces)
    shown = decimate_mesh(mesh, VIEW3D_MAX_TRIANGLES)
    h, w = fit.resolution
    factor = max(1, -(-max(h, w) // VIEW3D_MAX_TEXTURE))
    sets, imgs = {}, []
    for key, tex in (("fit", fit), ("truth", truth)):
        if tex is not None:
            sets[key], more = _set_textures(tex, key, factor)
            imgs += more
    th, tw = -(-h // factor), -(-w // factor)
    mfp_max = max([float(np.max(np.asarray(t.mfp)[np.asarray(t.model) == SUBSURFACE], initial=0.0))
                   for t in (fit, truth) if t is not None])
    if exposure is None or not np.isfinite(exposure):
        exposure, metered = _fallback_exposure(fit, env_path), "metered on the fitted maps' diffuse radiance"
    else:
        metered = "the rotation slider's"
    data = {
        "mesh": {"positions": _b64(shown.vertices, np.float32), "normals": _b64(shown.normals, np.float32),
                 "uv": _b64(shown.uv, np.float32), "curvature": _b64(vertex_curvature(shown), np.float32),
                 "indices": _b64(shown.faces, np.uint32), "vertices": len(shown.vertices),
                 "triangles": len(shown.faces), "source_triangles": n_faces},
        "sets": sets, "texture_size": [tw, th], "texture_factor": factor,
        "environment": environment,
        "mfp_max": mfp_max or 1.0, "sphere": _sphere_env(), "exposure": float(exposure), "error_gain": ERROR_GAIN,
        "camera": _camera(info, mesh), "eta": float(skin_bssrdf.SKIN_ETA),
        "t_avg": float(mean_transmittance(float(skin_bssrdf.SKIN_ETA))),
    }
    what = [f"{_MAP_NAMES[k]}" for k in sets]
    dec = (f"decimated from {n_faces:,} to {len(shown.faces):,} triangles" if len(shown.faces) < n_faces
           else f"{n_faces:,} triangles")
    size = f"{tw}x{th} texels" + (f" (block means of {factor}x{factor})" if factor > 1 else "")
    about = (f"{' and '.join(what)} on the mesh ({dec}), {size}; exposure {exposure:+.2f} EV ({metered}); "
             f"shading: SH irradiance + split-sum GGX of the environment, no shadows (see docs/cli.md)"
             + ("; " + "; ".join(notes) if notes else ""))
    body = (f'<p>{_esc(about)}</p><canvas id="v3d-canvas" width="640" height="480"></canvas>'
            f'{_controls(exposure, "truth" in sets)}<p class="note" id="v3d-status"></p>'
            f'<div hidden>{"".join(imgs)}</div>')
    script = "window.VIEW3D_DATA=" + _script_json(data) + ";\n" + _viewer_js()
    return body, script


_STYLE = ("<style>#v3d-canvas{width:640px;height:480px;background:#1f1f1f;cursor:grab;touch-action:none;"
          "display:block}#v3d-controls label{margin-right:10px}#v3d-controls div{margin:4px 0}"
          "#v3d-rot{width:360px;vertical-align:middle}</style>")


def _controls(exposure: float, has_truth: bool) -> str:
    """The 3D view's controls: rotation slider, fit | truth | error (truth and error disabled without a truth)
    and the error's gain, the map selector, the exposure."""
    sources = (("fit", "fit"), ("truth", "truth"), ("error", "error |fit − truth|"))
    radios = "".join(f'<label><input type="radio" name="v3d-source" value="{v}"{" checked" if v == "fit" else ""}'
                     f'{"" if v == "fit" or has_truth else " disabled"}> {lab}</label> ' for v, lab in sources)
    gains = "".join(f'<option value="{g:g}"{" selected" if g == ERROR_GAIN else ""}>{g:g}</option>'
                    for g in (1.0, 4.0, 16.0))
    maps = ("shaded", "diffuse albedo", "specular F0", "roughness (alpha)", "normal (world, 0.5 n + 0.5)",
            "mean free path (/ max)")
    options = "".join(f'<option value="{i}">{lab}</option>' for i, lab in enumerate(maps))
    return (f'{_STYLE}<div id="v3d-controls"><div><label for="v3d-rot">environment rotation about +y</label>'
            '<input type="range" id="v3d-rot" min="0" max="359" step="1" value="0"> '
            '<span id="v3d-rot-label">0°</span></div>'
            f'<div>{radios}<label for="v3d-gain">error ×</label><select id="v3d-gain">{gains}</select></div>'
            f'<div><label for="v3d-map">show</label><select id="v3d-map">{options}</select> '
            '<label for="v3d-exp">exposure (EV)</label><input type="number" id="v3d-exp" step="0.25" '
            f'value="{exposure:.2f}" style="width:70px"></div>'
            '<div class="note">drag to orbit, wheel to zoom, double-click to go back to the first view</div></div>')


def _viewer_js() -> str:
    """The viewer's script (package data ``relight/data/viewer3d.js``)."""
    return resources.files("relight.data").joinpath("viewer3d.js").read_text(encoding="utf-8")


def view3d_data(page: str) -> dict | None:
    """The ``window.VIEW3D_DATA`` object of a page's HTML (None when it has no 3D view): for tests and
    tools that read what a page embeds."""
    start = page.find("window.VIEW3D_DATA=")
    if start < 0:
        return None
    return json.JSONDecoder().raw_decode(page, start + len("window.VIEW3D_DATA="))[0]
