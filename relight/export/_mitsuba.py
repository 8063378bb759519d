"""Export a fitted texture set as a Mitsuba 3 scene (XML, ``version="3.0.0"``).

The scene folder is self-contained: ``scene.xml``, the mesh (``mesh.obj``,
written here from a ``stage.Mesh`` in the stage's millimetre frame, a copy of
a given .obj, or a given .ply converted to OBJ), the textures Mitsuba reads (converted from the texture
set, below) and a copy of the environment map. Render it with
``mitsuba scene.xml`` or ``mi.render(mi.load_file("scene.xml"))``.

BSDF mapping (and its approximations). The fitted model is
``f = rho_d / pi + D_GGX(alpha_x, alpha_y) F_Schlick(F0) G_Smith / (4 cos_i cos_o)``.
Mitsuba has no "sum" BSDF, so the scene uses the exact identity
``a + b = 0.5 (2a) + 0.5 (2b)`` with a ``blendbsdf`` of weight 0.5 between

* ``diffuse`` with ``reflectance`` = 2 rho_d (``mitsuba/diffuse_x2.exr``), and
* ``roughconductor`` with ``distribution="ggx"``, ``alpha_u``/``alpha_v`` the
  fitted alpha_x/alpha_y bitmaps (Mitsuba's alpha is the same GGX alpha, along
  the mesh's dP/du and its perpendicular, as ours), ``specular_reflectance`` = 2,
  ``k`` = 0 and ``eta`` = (1 + sqrt F0) / (1 - sqrt F0) per texel
  (``mitsuba/eta.exr``): a conductor with k = 0 has the dielectric Fresnel
  curve, whose value at normal incidence is exactly F0.

Approximations: (1) Fresnel is the exact dielectric curve instead of
Schlick's fit (equal at normal incidence; within ~0.01 absolute reflectance
at grazing angles for F0 ~ 0.03); (2) Mitsuba's Smith masking is the
separable (uncorrelated) form, like ``brdf``'s "smith"; (3) Blinn-Phong
samples are exported as GGX of the same alpha (the Walter et al. 2007 lobe
correspondence); (4) subsurface samples keep their total diffuse reflectance
as a local Lambert term (mainline Mitsuba 3 has no Burley BSSRDF), i.e. the
zero-mean-free-path limit; (5) the fitted shading normal enters through a
``normalmap`` wrapper (tangent-space map from the texture set, Mitsuba's frame
s = dP/du, matching the set's) only when it differs from the mesh normal,
with Mitsuba's terminator shadowing off (``use_shadowing_function``, Mitsuba
>= 3.7.1), since the fitted model has none.

``fresnel="schlick"`` writes the fitted model's Schlick Fresnel exactly
instead, for renders that must agree with ``relight.render`` to within Monte
Carlo noise (approximation (1) above is worth ~2% of a skin pixel's radiance):
``principled`` with metallic = 1 is GGX (separable Smith) with Schlick's
Fresnel of F0 = base_color (Mitsuba 3's ``calc_schlick``; checked against
``brdf`` to 1e-6), and it goes in a ``blendbsdf`` of weight w = 0.99 next to
``diffuse`` of reflectance rho_d / (1 - w), with base_color = F0 / w: exact
for the diffuse term and at normal incidence, and the Schlick grazing term
(1 - F0)(1 - cos)^5 is (w - F0) / (1 - F0), i.e. 1% low. Roughness is
sqrt(alpha); anisotropic maps become isotropic of alpha = sqrt(alpha_x alpha_y).

Camera: a ``perspective`` sensor with the vertical field of view from K
(fx = fy assumed; a mismatch is averaged), the OpenCV world-to-camera (R, t)
turned into Mitsuba's camera-to-world (x left, y up, z forward), the image size
as the film and the principal point as ``principal_point_offset_x/y``
(relative to the film size). Orthographic cameras are refused.

Texels no camera saw (``TextureSet.filled``) carry the texture set's fill
(``relight.io.UNSEEN_FILL``: the nearest seen texel's material, the mesh's own
normal), so the exported textures have no holes; the scene labels them: a
comment in scene.xml counts them and names the fill, and
``mitsuba/coverage.exr`` (Y: 1 where a camera saw the texel, 0 where the
texture holds the fill or gutter) is written beside the textures for a mask.
Mitsuba itself does not read that file.

Environment: an ``envmap`` emitter rotated 180 degrees about +y, which maps
Mitsuba's lat-long convention (u = 0 at -z... u = atan2(x, -z) / 2 pi) onto
``relight.envmap``'s (u = 0.5 at -z). The two also differ in what a pixel is:
``relight.envmap`` reads a map as piecewise constant, row i covering polar
angles [i, i + 1] pi / H; Mitsuba's ``envmap`` interpolates bilinearly between
nodes, row i at theta = i pi / (H - 1) (poles on the first and last rows) and
column j at u = (j + 0.5) / W (measured with ``emitter.eval``, Mitsuba 3.9).
Copied as is, a map would be stretched by up to half a row toward the poles
and blurred by one pixel. By default (``match_envmap``) the map is therefore
written as ``envmap.exr`` resampled for Mitsuba (:func:`mitsuba_envmap`):
``k`` times finer, each node the mean of the piecewise-constant map around it,
so Mitsuba's bilinear lookups return relight's pixels except within 1/k pixel
of their edges (a [1/4, 1/2, 1/4] blend at the fine scale, which keeps each
row's integral).
"""

from __future__ import annotations

import math
import os
import shutil
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..io import UNSEEN_FILL, read_exr, read_hdr, write_exr
from ..materials import BLINN_PHONG
from ..results import atomic_path, atomic_write_bytes

__all__ = ["mitsuba_envmap", "write_mitsuba_scene"]

SCENE_VERSION = "3.0.0"
# The tangent-space normal counts as "the mesh's own" when every covered texel
# is within this of (0, 0, 1): then no normalmap wrapper is written.
_FLAT_NORMAL_TOL = 1e-4
# Rows of the resampled environment map Mitsuba reads (at least): a pixel edge
# of a 1k map is then blended over 1/2 of its pixel, of the bundled 128-row
# maps over 1/8.
_ENV_MIN_ROWS = 1024
# Blend weight of the specular lobe for fresnel="schlick" (see the module docstring).
_SCHLICK_WEIGHT = 0.99


def mitsuba_envmap(radiance: np.ndarray, refine: int | None = None) -> np.ndarray:
    """A lat-long map for Mitsuba's ``envmap`` whose bilinear lookups return relight's pixels.

    Mitsuba's emitter interpolates bilinearly between nodes (row i at theta = i pi / (k H), column j at
    u = (j + 0.5) / (k W)); ``relight.envmap`` reads a map as piecewise constant (row i over polar angles
    [i, i + 1] pi / H). Each node row is the mean of the two rows of the nearest-refined map it separates,
    so a pixel edge is blended over 1/k pixel and every row keeps its integral; columns are nearest-refined
    (Mitsuba's column nodes are pixel centres).

    Args:
        radiance: the lat-long map [H, 2H, C] as relight reads it (ValueError for another shape).
        refine: the refinement k (default: the smallest even k with k H >= 1024).

    Returns:
        float32 [k H + 1, k W, C].
    """
    rad = np.asarray(radiance, np.float32)
    if rad.ndim != 3 or rad.shape[1] != 2 * rad.shape[0]:
        raise ValueError(f"radiance must be a lat-long map [H, 2H, C], got shape {list(rad.shape)}")
    h = rad.shape[0]
    k = int(refine) if refine is not None else max(2, 2 * math.ceil(_ENV_MIN_ROWS / (2 * h)))
    if k < 1:
        raise ValueError(f"refine must be >= 1, got {refine!r}")
    fine = np.repeat(np.repeat(rad, k, axis=0), k, axis=1)  # [k H, k W, C]
    # Node i lies between fine rows i - 1 and i (the poles: the first and last row).
    padded = np.concatenate([fine[:1], fine, fine[-1:]], axis=0)
    return (0.5 * (padded[:-1] + padded[1:])).astype(np.float32)


def _write_obj(path: Path, mesh) -> None:
    """Write a stage.Mesh as OBJ (v, vt, vn; faces v/vt/vn, 1-based)."""
    v = np.asarray(mesh.vertices, np.float64)
    n = np.asarray(mesh.normals, np.float64)
    f = np.asarray(mesh.faces, np.int64) + 1
    lines = ["# written by relight (stage frame, mm)"]
    lines += [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
    has_uv = mesh.uv is not None
    if has_uv:
        lines += [f"vt {a:.9g} {b:.9g}" for a, b in np.asarray(mesh.uv, np.float64)]
    lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in n]
    if has_uv:
        lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in f]
    else:
        lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in f]
    text = "\n".join(lines) + "\n"
    atomic_write_bytes(path, lambda fh: fh.write(text.encode()))


def _copy_atomic(src: Path, dst: Path) -> None:
    if src.resolve() == dst.resolve():
        return
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


def _camera_to_world(camera) -> np.ndarray:
    """Mitsuba's camera-to-world 4x4 (camera x left, y up, z forward) from OpenCV R, t."""
    R = np.asarray(camera.R, np.float64)
    t = np.asarray(camera.t, np.float64)
    center = -R.T @ t
    right, down, fwd = R[0], R[1], R[2]
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2], M[:3, 3] = -right, -down, fwd, center
    return M


def _matrix_text(M: np.ndarray) -> str:
    return " ".join(f"{x:.9g}" for x in np.asarray(M, np.float64).reshape(-1))


def _sub(parent, tag, **attrs):
    return ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})


def _bitmap(parent, name: str, filename: str, raw: bool = True):
    tex = _sub(parent, "texture", type="bitmap", name=name)
    _sub(tex, "string", name="filename", value=filename)
    _sub(tex, "boolean", name="raw", value="true" if raw else "false")
    _sub(tex, "string", name="filter_type", value="bilinear")
    return tex


def _check_camera(camera) -> None:
    """Mitsuba's perspective sensor is a pinhole without lens distortion: an orthographic camera is refused, a
    distortion left out with a warning."""
    if getattr(camera, "orthographic", False):
        raise ValueError("write_mitsuba_scene: orthographic cameras are not supported (use a pinhole camera)")
    if np.any(np.asarray(camera.dist) != 0):
        warnings.warn("write_mitsuba_scene: Mitsuba's perspective sensor has no lens distortion; the scene's "
                      "camera is the pinhole part of the camera (its renders are the undistorted view)", stacklevel=3)


def write_mitsuba_scene(folder: str | os.PathLike, mesh_path, textures, camera, envmap_path, *,
                        spp: int = 64, max_depth: int = 3, envmap_scale: float = 1.0,
                        terminator_shadowing: bool = False, match_envmap: bool = True,
                        fresnel: str = "dielectric") -> Path:
    """Write ``folder/scene.xml`` (Mitsuba 3) for a fitted texture set.

    Args:
        folder: the scene folder (created); textures, mesh and map copy go in it.
        mesh_path: a ``stage.Mesh`` (written as ``mesh.obj``, in the frame the
            camera and maps use), or the path of an .obj/.ply already in that
            frame (.obj copied). Mitsuba flips OBJ texture v on load, which
            matches the set's row-0-at-v=1 orientation, but not PLY's (its
            textures would come out v-flipped), so a .ply is read with
            ``stage.load_mesh`` and written as ``mesh.obj``.
        textures: a ``relight.io.TextureSet`` (``relight.io.read_maps``).
        camera: a pinhole ``stage.Camera`` (a lens distortion is left out, with a warning).
        envmap_path: lat-long .hdr/.exr environment map (copied into the folder).
        spp, max_depth: integrator settings (``path``; depth 3 = direct light
            plus one bounce, enough for a single head).
        envmap_scale: multiplies the map's radiance.
        terminator_shadowing: keep Mitsuba's normal-map terminator shadowing
            (Conty Estevez et al. 2019; not part of the fitted model). The
            ``use_shadowing_function`` parameter needs Mitsuba >= 3.7.1; it is
            written only when the scene has a normal map.
        match_envmap: write the map as ``envmap.exr`` resampled by
            :func:`mitsuba_envmap` so that Mitsuba sees the piecewise-constant
            map ``relight.envmap`` renders with (default); False copies the
            file as is (Mitsuba then reads its rows as nodes from pole to
            pole, bilinearly: a stretch of up to half a row).
        fresnel: "dielectric" (default: ``roughconductor`` with the exact
            dielectric curve of F0) or "schlick" (``principled`` metallic,
            the fitted model's Schlick Fresnel; see the module docstring).

    Returns:
        The path of scene.xml. See the module docstring for the BSDF mapping, and for the label of texels
        no camera saw (a scene.xml comment and ``mitsuba/coverage.exr``).
    """
    folder = Path(folder)
    if fresnel not in ("dielectric", "schlick"):
        raise ValueError(f"fresnel must be 'dielectric' or 'schlick', got {fresnel!r}")
    envmap_path = Path(envmap_path)
    if not envmap_path.is_file():
        raise FileNotFoundError(f"{envmap_path}: environment map not found")
    _check_camera(camera)
    folder.mkdir(parents=True, exist_ok=True)
    tex_dir = folder / "mitsuba"
    tex_dir.mkdir(exist_ok=True)

    # Mesh.
    if isinstance(mesh_path, (str, os.PathLike)):
        src = Path(mesh_path)
        if not src.is_file():
            raise FileNotFoundError(f"{src}: mesh file not found")
        if src.suffix.lower() not in (".obj", ".ply"):
            raise ValueError(f"{src}: Mitsuba export needs an .obj or .ply mesh (or pass a stage.Mesh)")
        mesh_name = "mesh.obj"
        if src.suffix.lower() == ".obj":
            _copy_atomic(src, folder / mesh_name)
        else:
            import stage

            _write_obj(folder / mesh_name, stage.load_mesh(src))
    else:
        mesh_name = "mesh.obj"
        _write_obj(folder / mesh_name, mesh_path)

    # Textures Mitsuba reads (see the module docstring for why these).
    cov = textures.coverage
    model = textures.model
    f0 = np.clip(textures.specular[..., 0].astype(np.float64), 0.0, 0.99)
    sq = np.sqrt(f0)
    eta = (1.0 + sq) / (1.0 - sq)
    diffuse = np.asarray(textures.albedo, np.float64).copy()
    # Subsurface samples: total diffuse reflectance as a local Lambert term (already rho_d).
    alpha = np.asarray(textures.alpha, np.float64).copy()
    iso = model <= BLINN_PHONG
    alpha[..., 1] = np.where(iso, alpha[..., 0], alpha[..., 1])
    write_exr(tex_dir / "diffuse_x2.exr", (2.0 * diffuse).astype(np.float32))
    write_exr(tex_dir / "alpha_u.exr", alpha[..., 0].astype(np.float32))
    write_exr(tex_dir / "alpha_v.exr", alpha[..., 1].astype(np.float32))
    write_exr(tex_dir / "eta.exr", eta.astype(np.float32))
    if fresnel == "schlick":
        w = _SCHLICK_WEIGHT
        write_exr(tex_dir / "diffuse_blend.exr", (diffuse / (1.0 - w)).astype(np.float32))
        write_exr(tex_dir / "base_color.exr", np.repeat((f0 / w)[..., None], 3, -1).astype(np.float32))
        rough = np.sqrt(np.sqrt(np.maximum(alpha[..., 0], 0.0) * np.maximum(alpha[..., 1], 0.0)))
        write_exr(tex_dir / "roughness.exr", rough.astype(np.float32))
    filled = getattr(textures, "filled", None)
    filled = np.zeros_like(cov, bool) if filled is None else np.asarray(filled, bool)
    note = None
    if filled.any():
        # Label the fill: a mask beside the textures and a comment in the scene (Mitsuba reads neither).
        write_exr(tex_dir / "coverage.exr", cov.astype(np.float32))
        note = (f"{int(filled.sum())} of the {int((cov | filled).sum())} texels, which no camera saw, carry the "
                f"texture set's fill ({UNSEEN_FILL}: the nearest seen texel's material, the mesh's normal; not "
                "measurements); mitsuba/coverage.exr is 1 where a camera saw the texel")
    n_ts = np.asarray(textures.normal_ts, np.float64)
    use_normalmap = bool(np.any(np.abs(n_ts[cov] - [0.0, 0.0, 1.0]) > _FLAT_NORMAL_TOL))
    if use_normalmap:
        write_exr(tex_dir / "normal_ts.exr", (0.5 * n_ts + 0.5).astype(np.float32))
    if match_envmap:
        suffix = envmap_path.suffix.lower()
        if suffix not in (".hdr", ".exr"):
            raise ValueError(f"{envmap_path}: environment map must be .hdr or .exr")
        env = read_hdr(envmap_path) if suffix == ".hdr" else read_exr(envmap_path)
        env_name = "envmap.exr"
        write_exr(folder / env_name, mitsuba_envmap(np.asarray(env)[..., :3]))
    else:
        env_name = "envmap" + envmap_path.suffix.lower()
        _copy_atomic(envmap_path, folder / env_name)

    # Scene.
    scene = ET.Element("scene", version=SCENE_VERSION)
    # Overridable at load time: mi.load_file(path, spp=4, max_depth=2) or ``mitsuba -D spp=4``.
    _sub(scene, "default", name="spp", value=int(spp))
    _sub(scene, "default", name="max_depth", value=int(max_depth))
    integ = _sub(scene, "integrator", type="path")
    _sub(integ, "integer", name="max_depth", value="$max_depth")

    K = np.asarray(camera.K, np.float64)
    fy = 0.5 * (K[0, 0] + K[1, 1])
    fov = 2.0 * math.degrees(math.atan(0.5 * camera.height / fy))
    sensor = _sub(scene, "sensor", type="perspective")
    _sub(sensor, "string", name="fov_axis", value="y")
    _sub(sensor, "float", name="fov", value=f"{fov:.9g}")
    _sub(sensor, "float", name="near_clip", value="1")
    _sub(sensor, "float", name="far_clip", value="100000")
    # Mitsuba's ray for film position s goes through its centred camera's s + offset (perspective.cpp,
    # sample_ray), so the principal point sits at s = 1/2 - offset: the offset is minus cx's (cy's) distance
    # from the film's centre, as fractions of the film (the Camera's continuous pixel coordinates).
    ppx = (0.5 * camera.width - K[0, 2]) / camera.width
    ppy = (0.5 * camera.height - K[1, 2]) / camera.height
    if abs(ppx) > 1e-9 or abs(ppy) > 1e-9:
        _sub(sensor, "float", name="principal_point_offset_x", value=f"{ppx:.9g}")
        _sub(sensor, "float", name="principal_point_offset_y", value=f"{ppy:.9g}")
    tw = _sub(sensor, "transform", name="to_world")
    _sub(tw, "matrix", value=_matrix_text(_camera_to_world(camera)))
    sampler = _sub(sensor, "sampler", type="independent")
    _sub(sampler, "integer", name="sample_count", value="$spp")
    film = _sub(sensor, "film", type="hdrfilm")
    _sub(film, "integer", name="width", value=int(camera.width))
    _sub(film, "integer", name="height", value=int(camera.height))
    _sub(film, "rfilter", type="box")

    emitter = _sub(scene, "emitter", type="envmap")
    _sub(emitter, "string", name="filename", value=env_name)
    _sub(emitter, "float", name="scale", value=f"{float(envmap_scale):.9g}")
    et = _sub(emitter, "transform", name="to_world")
    _sub(et, "rotate", y="1", angle="180")

    shape = _sub(scene, "shape", type=mesh_name.rsplit(".", 1)[1])
    _sub(shape, "string", name="filename", value=mesh_name)
    _sub(shape, "boolean", name="face_normals", value="false")
    outer = shape
    if use_normalmap:
        outer = _sub(shape, "bsdf", type="normalmap")
        _bitmap(outer, "normalmap", "mitsuba/normal_ts.exr", raw=True)
        # Mitsuba >= 3.7.1 attenuates normal-mapped shading by the terminator
        # shadowing of Conty Estevez et al. 2019 by default; the fitted model
        # has no such term, so it is off unless asked for.
        _sub(outer, "boolean", name="use_shadowing_function", value="true" if terminator_shadowing else "false")
    blend = _sub(outer, "bsdf", type="blendbsdf")
    if fresnel == "schlick":
        _sub(blend, "float", name="weight", value=f"{_SCHLICK_WEIGHT:.9g}")
        diff = _sub(blend, "bsdf", type="diffuse")
        _bitmap(diff, "reflectance", "mitsuba/diffuse_blend.exr", raw=True)
        pr = _sub(blend, "bsdf", type="principled")
        _bitmap(pr, "base_color", "mitsuba/base_color.exr", raw=True)
        _bitmap(pr, "roughness", "mitsuba/roughness.exr", raw=True)
        _sub(pr, "float", name="metallic", value="1")
        _sub(pr, "float", name="spec_tint", value="0")
        _sub(pr, "float", name="anisotropic", value="0")
        return _write_xml(folder, scene, note)
    _sub(blend, "float", name="weight", value="0.5")
    diff = _sub(blend, "bsdf", type="diffuse")
    # raw: linear EXR data used as is (2 rho_d may exceed 1, which Mitsuba's
    # spectral reflectance check would refuse; the blend weight brings it back).
    _bitmap(diff, "reflectance", "mitsuba/diffuse_x2.exr", raw=True)
    cond = _sub(blend, "bsdf", type="roughconductor")
    _sub(cond, "string", name="distribution", value="ggx")
    _bitmap(cond, "alpha_u", "mitsuba/alpha_u.exr")
    _bitmap(cond, "alpha_v", "mitsuba/alpha_v.exr")
    _bitmap(cond, "eta", "mitsuba/eta.exr")
    _sub(cond, "rgb", name="k", value="0")
    _sub(cond, "float", name="specular_reflectance", value="2")

    return _write_xml(folder, scene, note)


def _write_xml(folder: Path, scene, note: str | None = None) -> Path:
    ET.indent(scene)
    comment = ("<!-- relight texture set exported for Mitsuba 3: rho_d/pi + GGX specular as a blendbsdf "
               "(the mapping: relight/export/_mitsuba.py, docs/cli.md). Lengths in mm. -->\n")
    if note is not None:
        comment += f"<!-- relight unseen texels: {note.replace('--', '-')}. -->\n"
    xml = '<?xml version="1.0" encoding="utf-8"?>\n' + comment + ET.tostring(scene, encoding="unicode") + "\n"
    path = folder / "scene.xml"
    atomic_write_bytes(path, lambda fh: fh.write(xml.encode()))
    return path

