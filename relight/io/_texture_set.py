"""Fitted material maps as an OpenEXR texture set that DCC tools and renderers load.

Layout (format ``relight-maps``, version 1), all images ``[H, W]`` on the
surface's texel grid (row 0 at v = 1, the usual image orientation), linear float:

==================== =========================== ==============================================
file                 channels                    meaning
==================== =========================== ==============================================
albedo.exr           R, G, B                     diffuse albedo rho_d (linear, 0..1)
specular.exr         Y                           specular albedo rho_s (Schlick F0 on the GGX rungs)
roughness.exr        alpha_x, alpha_y, Y         GGX alpha along the tangent / bitangent;
                                                 Y = sqrt(alpha_x alpha_y) for one-channel tools
normal.exr           R, G, B                     tangent-space normal, encoded 0.5 n + 0.5
                                                 (OpenGL/MikkTSpace-style: +Y along the bitangent)
                     world.R, world.G, world.B   world-space unit normal, raw (-1..1)
                     tangent.R, tangent.G, .B    world-space unit tangent of the fitted frame, raw
mean_free_path.exr   R, G, B                     diffuse mean free path, mm (Burley ``dmfp``)
model.exr            Y                           model-ladder index (see maps.json ``models``)
coverage.exr         Y                           1 on texels some camera saw (a fitted sample), 0 on
                                                 texels no camera saw and in the gutter
                     filled                      1 on texels no camera saw (inside the atlas; their
                                                 maps hold the fill below), 0 elsewhere
maps.json            --                          format, version, resolution, surface (mesh path,
                                                 scale, centring, units), the model legend, the
                                                 file table and free-form metadata
==================== =========================== ==============================================

The tangent-space normal is expressed in the surface's own shading frame at
each texel (``stage.texel_samples``: t = dP/du made orthogonal to the
interpolated normal, b = n x t), the frame renderers build from the mesh's UVs.

Texels outside the UV charts are filled from their valid neighbours for
``gutter`` rings (the usual bake padding, ``relight._preview.dilate``; nearest
value for the model index, renormalised for normals) so a bilinear lookup at
a chart border does not blend in the empty background. ``coverage.exr``
tells fitted texels from padding.

Texels no camera saw (``seen`` False: ``relight fit``'s photo-capture texels
seen by fewer than ``min_views`` cameras, a texel capture's texels without a
valid observation) hold no measurement. They are coverage 0 and ``filled`` 1
in ``coverage.exr``, and their maps hold an explicit fill (``UNSEEN_FILL``,
recorded in maps.json ``unseen``) so exported textures have no holes: diffuse albedo,
specular albedo, roughness, mean free path and model rung are copied from the
nearest seen texel on the surface (3D distance between texel centres, so UV
seams do not matter), and the shading frame is the mesh's own (tangent-space
normal (0, 0, 1)). A reader that wants only measurements masks by coverage.

``texture_set(maps, surface)`` builds the set in memory (a :class:`TextureSet`,
what reading the files back gives); ``write_texture_set`` writes one and
``write_maps`` does both, building and writing one file's maps at a time (the
same bytes, without the whole set in memory). A set is written as a unit
(``relight.results.result_set``: built in a temporary sibling folder,
the result-set manifest ``relight-set.json`` with every file's SHA-256 last,
then swapped into place; the folder is locked meanwhile). Reading validates
everything and raises ``FileNotFoundError`` or ``ImageFormatError`` (a
``ValueError``) naming the file and the problem; a set whose files do not all
match its manifest (old and new files mixed by an interrupted writer, or an
edit) is refused too (an ``ImageFormatError`` from the
``relight.results.ResultSetError``).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import stage

from ..image._preview import dilate
from ..materials._maps import MODELS, MaterialMaps, material_maps
from ..results import ResultSetError, open_result_set, result_set, writing
from ._errors import ImageFormatError, format_version, set_refusal_as
from ._exr import read_exr_channels, write_exr_channels
from ._json import jsonable, read_json, write_json

__all__ = ["UNSEEN_FILL", "TextureSet", "fill_unseen", "is_map_set", "read_maps", "texture_set", "write_maps",
           "write_texture_set", "write_texture_set_files"]

FORMAT = "relight-maps"
VERSION = 1
# File -> channels, the layout in the module docstring.
# The fill of texels no camera saw (module docstring), as maps.json's ``unseen.fill`` names it.
UNSEEN_FILL = "nearest_seen"
FILL_ABOUT = ("texels no camera saw: coverage.exr Y 0, filled 1; diffuse albedo, specular albedo, roughness, "
              "mean free path and model copied from the nearest seen texel on the surface (3D), shading normal "
              "the mesh's own; not measurements")
FILES = {
    "albedo": ("albedo.exr", ("R", "G", "B")),
    "specular": ("specular.exr", ("Y",)),
    "roughness": ("roughness.exr", ("alpha_x", "alpha_y", "Y")),
    "normal": ("normal.exr", ("R", "G", "B", "world.R", "world.G", "world.B", "tangent.R", "tangent.G", "tangent.B")),
    "mean_free_path": ("mean_free_path.exr", ("R", "G", "B")),
    "model": ("model.exr", ("Y",)),
    "coverage": ("coverage.exr", ("Y", "filled")),
}
# Channels a reader does without (sets written before they existed): channel -> what it reads as.
OPTIONAL = {("coverage", "filled"): 0.0}
# Rings of gutter texels filled around each chart: enough for bilinear
# lookups plus one coarser mip level.
DEFAULT_GUTTER = 4


@dataclasses.dataclass(frozen=True)
class TextureSet:
    """A texture set in memory: every map ``[H, W, C]`` on the texel grid.

    albedo [H, W, 3], specular [H, W, 1], alpha [H, W, 2], normal (world)
    [H, W, 3], tangent (world) [H, W, 3], normal_ts (tangent space, decoded to
    -1..1) [H, W, 3], mfp [H, W, 3] (mm), model [H, W] int32, coverage
    [H, W] bool (texels some camera saw); ``info`` holds maps.json; filled
    [H, W] bool: texels no camera saw, whose maps hold the fill
    (``UNSEEN_FILL``; None: none)."""

    albedo: np.ndarray
    specular: np.ndarray
    alpha: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    normal_ts: np.ndarray
    mfp: np.ndarray
    model: np.ndarray
    coverage: np.ndarray
    info: dict
    filled: np.ndarray | None = None

    def __post_init__(self):
        if self.filled is None:
            object.__setattr__(self, "filled", np.zeros(np.shape(self.coverage), bool))

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.coverage.shape)

    @property
    def surface_info(self) -> dict:
        return dict(self.info.get("surface", {}))

    def maps(self, surface) -> MaterialMaps:
        """The maps at ``surface``'s samples (looked up at ``surface.texel_index``)
        as :class:`relight.MaterialMaps`. The surface must live on this set's
        texel grid; samples on texels that are neither covered nor filled (the
        gutter) are refused."""
        if tuple(surface.resolution) != self.resolution:
            raise ValueError(f"texture set is {self.resolution[0]}x{self.resolution[1]} texels but the surface's "
                             f"grid is {surface.resolution[0]}x{surface.resolution[1]}")
        idx = np.asarray(surface.texel_index)
        flat = lambda a: a.reshape((-1,) + a.shape[2:])[idx]  # noqa: E731
        on = flat(self.coverage | self.filled)
        if not np.all(on):
            n = int(np.sum(~on))
            raise ValueError(f"{n} surface sample(s) fall on texels the texture set does not cover")
        return material_maps(surface, flat(self.albedo), flat(self.specular), flat(self.alpha),
                             normal=flat(self.normal), tangent=flat(self.tangent), mfp=flat(self.mfp),
                             model=flat(self.model))


def is_map_set(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` looks like a texture set (has a maps.json of this format)."""
    p = Path(folder) / "maps.json"
    if not p.is_file():
        return False
    try:
        return stage.parse_json(p.read_bytes(), p).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def _dilate_nearest(values: np.ndarray, valid: np.ndarray, iterations: int) -> np.ndarray:
    """Gutter fill for categorical maps: copy a valid 4-neighbour (no averaging)."""
    out = np.array(values, copy=True)
    ok = np.array(valid, bool, copy=True)
    for _ in range(iterations):
        grow = np.zeros_like(ok)
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            src_ok = np.roll(ok, (dy, dx), axis=(0, 1))
            take = ~ok & ~grow & src_ok
            out[take] = np.roll(out, (dy, dx), axis=(0, 1))[take]
            grow |= take
        ok |= grow
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-12, v / np.where(n > 1e-12, n, 1.0), np.array([0.0, 0.0, 1.0], v.dtype))


# Texture rows renormalised per band (_Maps._renorm): 64 rows of 4096 texels' float64 temporaries are ~20 MiB.
_RENORM_ROWS = 64


class _Maps:
    """The fields of a :class:`TextureSet` of ``maps`` over ``surface``, each
    built when asked for (``get``) and not kept, so a caller that writes one
    file at a time holds one map's textures and their sources, not all of them."""

    def __init__(self, maps: MaterialMaps, surface, gutter: int, seen=None):
        P = surface.num_samples
        if maps.num_samples != P:
            raise ValueError(f"maps hold {maps.num_samples} samples but the surface has {P}")
        h, w = surface.resolution
        idx = np.asarray(surface.texel_index)
        if len(np.unique(idx)) != len(idx):
            raise ValueError("surface has several samples on one texel; a texture set needs one per texel")
        seen = np.ones(P, bool) if seen is None else np.asarray(seen, bool)
        if seen.shape != (P,):
            raise ValueError(f"seen must be bool [{P}] (one per surface sample), got shape {seen.shape}")
        if not seen.any():
            raise ValueError("no surface sample is seen: a texture set needs at least one measured texel")
        self.n_unseen = int(P - seen.sum())
        if self.n_unseen:
            maps = fill_unseen(maps, surface, seen)
        self.maps, self.surface, self.gutter, self.P = maps, surface, gutter, P
        self.valid = np.zeros((h, w), bool)
        self.valid.reshape(-1)[idx] = True
        self.covered = np.zeros((h, w), bool)
        self.covered.reshape(-1)[idx[seen]] = True

    def _tex(self, x, fill=0.0):
        x = np.asarray(x, np.float32)
        return self.surface.to_texture(x.reshape(self.P, -1), fill=fill)

    def _pad(self, t):
        return dilate(t, self.valid, self.gutter)

    def _renorm(self, t):
        """Padded and renormalised (in float64, rounded to float32), a band of
        rows at a time: per texel the same arithmetic, a band's temporaries."""
        out = self._pad(t)
        for r in range(0, out.shape[0], _RENORM_ROWS):
            out[r:r + _RENORM_ROWS] = _unit(out[r:r + _RENORM_ROWS].astype(np.float64))
        return out

    def _frames(self):
        """World normal and tangent (float64, unit, t orthogonal to n) of the maps."""
        n_world = _unit(np.asarray(self.maps.normal, np.float64))
        t_world = np.asarray(self.maps.tangent, np.float64)
        return n_world, _unit(t_world - np.sum(t_world * n_world, -1, keepdims=True) * n_world)

    def get(self, field: str) -> np.ndarray:
        """The TextureSet field ``field`` (everything but ``info``)."""
        m = self.maps
        if field == "albedo":
            return self._pad(self._tex(m.rho_d))
        if field == "specular":
            return self._pad(self._tex(m.rho_s))
        if field == "alpha":
            return self._pad(self._tex(np.asarray(m.alpha, np.float64), fill=1.0))
        if field == "normal":
            return self._renorm(self._tex(self._frames()[0]))
        if field == "tangent":
            return self._renorm(self._tex(self._frames()[1]))
        if field == "normal_ts":
            # Tangent-space normal in the surface's own frame (t, b, n).
            n_world = self._frames()[0]
            sn, st, sb = (np.asarray(a, np.float64) for a in
                          (self.surface.normal, self.surface.tangent, self.surface.bitangent))
            n_ts = np.stack([np.sum(n_world * st, -1), np.sum(n_world * sb, -1), np.sum(n_world * sn, -1)], -1)
            del n_world
            return self._renorm(self._tex(n_ts))
        if field == "mfp":
            return self._pad(self._tex(m.mfp))
        if field == "model":
            return _dilate_nearest(self.surface.to_texture(np.asarray(m.model, np.int32)), self.valid,
                                   self.gutter).astype(np.int32)
        if field == "coverage":
            return self.covered
        if field == "filled":
            return self.valid & ~self.covered
        raise KeyError(field)


def _file_channels(key: str, get) -> dict[str, np.ndarray]:
    """The channels of file ``key`` of FILES, from the TextureSet fields ``get(field)`` gives."""
    if key == "albedo":
        a = get("albedo")
        return {c: a[..., i] for i, c in enumerate("RGB")}
    if key == "specular":
        return {"Y": get("specular")[..., 0]}
    if key == "roughness":
        a = get("alpha")
        return {"alpha_x": a[..., 0], "alpha_y": a[..., 1], "Y": np.sqrt(a[..., 0] * a[..., 1])}
    if key == "normal":
        enc = 0.5 * get("normal_ts") + 0.5
        n, t = get("normal"), get("tangent")
        return {**{c: enc[..., i] for i, c in enumerate("RGB")},
                **{f"world.{c}": n[..., i] for i, c in enumerate("RGB")},
                **{f"tangent.{c}": t[..., i] for i, c in enumerate("RGB")}}
    if key == "mean_free_path":
        m = get("mfp")
        return {c: m[..., i] for i, c in enumerate("RGB")}
    if key == "model":
        return {"Y": get("model").astype(np.float32)}
    if key == "coverage":
        return {"Y": get("coverage").astype(np.float32), "filled": get("filled").astype(np.float32)}
    raise KeyError(key)


def fill_unseen(maps: MaterialMaps, surface, seen) -> MaterialMaps:
    """``maps`` with the samples no camera saw given the texture set's fill (``UNSEEN_FILL``, module docstring).

    Args:
        maps: :class:`relight.MaterialMaps` over ``surface``'s samples.
        surface: the ``stage.Surface`` (its ``position`` [P, 3] finds the nearest seen sample).
        seen: bool [P], the samples some camera saw (at least one).

    Returns:
        The maps with every unseen sample's diffuse albedo, specular albedo, roughness, mean free path and
        model rung copied from the nearest seen sample (Euclidean distance between sample positions, ties to
        the lower index), and its shading normal and tangent the surface's own; seen samples unchanged.
    """
    from scipy.spatial import cKDTree

    seen = np.asarray(seen, bool)
    pos = np.asarray(surface.position, np.float64)
    on, off = np.flatnonzero(seen), np.flatnonzero(~seen)
    if off.size == 0:
        return maps
    _, k = cKDTree(pos[on]).query(pos[off])
    src = on[k]

    def copy(a, take):
        a = np.array(a, copy=True)
        a[off] = take[off] if take is not None else a[src]
        return a

    return material_maps(surface, copy(maps.rho_d, None), copy(maps.rho_s, None), copy(maps.alpha, None),
                         normal=copy(maps.normal, np.asarray(surface.normal, np.asarray(maps.normal).dtype)),
                         tangent=copy(maps.tangent, np.asarray(surface.tangent, np.asarray(maps.tangent).dtype)),
                         mfp=copy(maps.mfp, None), model=copy(maps.model, None))


def _info(surface, P: int, gutter: int, metadata, surface_info, n_unseen: int = 0) -> dict:
    """maps.json of a set over ``surface`` (P samples, ``n_unseen`` of them filled)."""
    h, w = surface.resolution
    return {
        "format": FORMAT,
        "version": VERSION,
        "resolution": [int(h), int(w)],
        "samples": int(P),
        "gutter": int(gutter),
        "unseen": {"texels": int(n_unseen), "fill": UNSEEN_FILL, "about": FILL_ABOUT},
        "models": {str(i): m for i, m in enumerate(MODELS)},
        "units": {"albedo": "1 (linear)", "specular": "1 (Schlick F0)", "roughness": "GGX alpha",
                  "mean_free_path": "mm", "normal": "unit vectors; R,G,B tangent space encoded 0.5 n + 0.5",
                  "lengths": "mm"},
        "files": {key: {"file": name, "channels": list(ch)} for key, (name, ch) in FILES.items()},
        "surface": {**jsonable(dict(surface_info or {})), "resolution": [int(h), int(w)]},
        "metadata": jsonable(dict(metadata or {})),
        "writer": f"relight {_version()}",
    }


def texture_set(maps: MaterialMaps, surface, *, metadata: Mapping | None = None,
                surface_info: Mapping | None = None, gutter: int = DEFAULT_GUTTER, seen=None) -> TextureSet:
    """The texture set of ``maps`` (over ``surface``'s samples), in memory: what
    :func:`write_maps` writes and :func:`read_maps` reads back (to the float32
    rounding of the EXR files), without touching the disk.

    Args: as :func:`write_maps`. ``info`` holds what maps.json will hold.
    """
    src = _Maps(maps, surface, gutter, seen)
    fields = {f.name: src.get(f.name) for f in dataclasses.fields(TextureSet) if f.name != "info"}
    return TextureSet(**fields, info=_info(surface, src.P, gutter, metadata, surface_info, src.n_unseen))


# The result-set kind of a map set written by write_maps / write_texture_set (relight fit's is "fit").
KIND = "maps"
# Every file a reader takes: verified against the set's manifest.
SET_FILES = ("maps.json", *(name for name, _ in FILES.values()))


def _write_files(folder: Path, get, info: dict) -> Path:
    """Each file of FILES from ``get(field)`` (built per file and dropped before
    the next), each atomically, then maps.json ``info`` last, into ``folder``
    as it is (the caller makes it a unit)."""
    folder.mkdir(parents=True, exist_ok=True)
    for key, (name, _) in FILES.items():
        with writing(folder / name):
            write_exr_channels(folder / name, _file_channels(key, get), header={"relight.map": key})
    with writing(folder / "maps.json"):
        write_json(folder / "maps.json", info)
    return folder


def _write_set(folder: Path, get, info: dict) -> Path:
    # carry: a library caller may keep its own files beside the maps (a rig.json); they are carried into the set.
    with result_set(folder, KIND, command="relight.io.write_maps", carry=True) as tmp:
        _write_files(tmp, get, info)
    return folder


def write_texture_set_files(folder: str | os.PathLike, textures: TextureSet) -> Path:
    """The files of :func:`write_texture_set` written into ``folder`` as it is
    (no manifest, no swap): for a caller that builds a larger result set
    around them (``relight fit``'s)."""
    return _write_files(Path(folder), lambda field: getattr(textures, field), textures.info)


def write_texture_set(folder: str | os.PathLike, textures: TextureSet) -> Path:
    """Write an in-memory :class:`TextureSet` (from :func:`texture_set`) to
    ``folder`` in the layout of the module docstring, as a unit: built in a
    temporary sibling, manifest last, swapped in (an existing map set is
    replaced; other files in ``folder`` are carried into the new set).
    Returns the folder."""
    return _write_set(Path(folder), lambda field: getattr(textures, field), textures.info)


def write_maps(folder: str | os.PathLike, maps: MaterialMaps, surface, *, metadata: Mapping | None = None,
               surface_info: Mapping | None = None, gutter: int = DEFAULT_GUTTER, seen=None) -> Path:
    """Write ``maps`` (over ``surface``'s samples) as a texture set in ``folder``:
    the files of ``write_texture_set(folder, texture_set(maps, surface, ...))``,
    bit for bit, but each map is built, written and dropped before the next, so
    peak memory is one file's textures (the normal file's three, ~100 B a grid
    texel with their float64 sources) rather than the whole set's.

    Args:
        folder: created if missing; an existing map set there is replaced
            as a unit (built beside it, swapped in); other files in it are
            carried into the new set (and listed in its manifest).
        maps: :class:`relight.MaterialMaps` with one row per surface sample.
        surface: the ``stage.Surface`` the maps are over (texel grid, frame).
        metadata: JSON-able extras stored under maps.json ``metadata``.
        surface_info: how to rebuild the surface (mesh path, scale, centring),
            stored under maps.json ``surface``; resolution is added.
        gutter: rings of padding texels filled around each UV chart.
        seen: bool [P], the samples some camera saw; the others are coverage 0 and hold the fill
            (:func:`fill_unseen`, the module docstring). None: every sample.

    Returns the folder.
    """
    try:
        src = _Maps(maps, surface, gutter, seen)
    except ValueError as err:
        raise ValueError(f"{folder}: {err}") from None
    return _write_set(Path(folder), src.get, _info(surface, src.P, gutter, metadata, surface_info, src.n_unseen))


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("lightstage-relight")
    except Exception:  # not installed: running from a checkout
        return "unknown"


def _read_header(meta_path: Path) -> tuple[dict, tuple[int, int]]:
    """maps.json's contents and its resolution (H, W), checked: format, version, resolution."""
    info = read_json(meta_path, "a map-set folder needs maps.json and the EXR maps")
    fmt = info.get("format") if isinstance(info, dict) else None
    if fmt != FORMAT:
        raise ImageFormatError(f"{meta_path}: not a relight map set (format {fmt!r}, expected {FORMAT!r})")
    format_version(info, meta_path, VERSION, default=VERSION)
    try:
        res = tuple(int(r) for r in info["resolution"])
        assert len(res) == 2 and min(res) > 0
    except (KeyError, TypeError, ValueError, AssertionError):
        raise ImageFormatError(f"{meta_path}: field 'resolution' must be [H, W] with positive sizes, "
                               f"got {info.get('resolution')!r}") from None
    return info, res


def _read_map_file(path: Path, key: str, names, res: tuple[int, int]) -> dict[str, np.ndarray]:
    """The channels ``names`` of the map file ``path`` (FILES' ``key``), checked: present (or OPTIONAL),
    ``res`` texels, finite."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing from the map set ({key} map)")
    c, _ = read_exr_channels(path)
    for n in names:
        if n not in c and (key, n) in OPTIONAL:
            c[n] = np.full(res, OPTIONAL[key, n], np.float32)
    missing = [n for n in names if n not in c]
    if missing:
        raise ImageFormatError(f"{path}: channel(s) {missing} missing; the file has {sorted(c)}")
    for n in names:
        if c[n].shape != res:
            raise ImageFormatError(f"{path}: map is {c[n].shape[0]}x{c[n].shape[1]} texels but maps.json says "
                                   f"{res[0]}x{res[1]}")
        if not np.all(np.isfinite(c[n])):
            raise ImageFormatError(f"{path}: channel {n!r} has NaN or Inf values")
    return {n: np.asarray(c[n], np.float32) for n in names}


def read_maps(folder: str | os.PathLike, *, building: bool = False) -> tuple[TextureSet, dict]:
    """Read and validate a texture set written by :func:`write_maps`.

    Returns ``(textures, surface_info)``: a :class:`TextureSet` and maps.json's
    ``surface`` entry (mesh path, scale, centring, resolution) from which the
    caller rebuilds the texel surface (``TextureSet.maps(surface)`` then gives
    :class:`relight.MaterialMaps`).

    Raises FileNotFoundError (folder, maps.json or a map missing) or
    ImageFormatError (corrupt EXR, missing channel, wrong resolution, bad
    maps.json), each naming the file; also ImageFormatError (from the
    ``relight.results.ResultSetError`` it chains) when the folder has no
    result-set manifest or a file differs from it (a mix of two writes),
    checked after the content so that a damaged file is named for what is
    wrong with it. ``building=True``: the folder is a result set this process
    is still writing (its manifest comes last; the results viewer's page of a
    fit is built there before the commit): every file is read and checked, the
    manifest is not asked for.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such map-set folder")
    # Opened first: the folder's identity then is what the files must still belong to.
    rs = None if building else _open_set(folder)
    meta_path = folder / "maps.json"
    info, res = _read_header(meta_path)
    chans = {key: _read_map_file(folder / name, key, names, res) for key, (name, names) in FILES.items()}
    st = lambda key, names: np.stack([chans[key][n] for n in names], -1)  # noqa: E731
    seen = chans["coverage"]["Y"] > 0.5
    filled = chans["coverage"]["filled"] > 0.5
    if not seen.any():
        raise ImageFormatError(f"{folder / 'coverage.exr'}: covers no texel")
    if np.any(seen & filled):
        raise ImageFormatError(f"{folder / 'coverage.exr'}: {int(np.sum(seen & filled))} texel(s) are both covered "
                               "(Y) and filled (no camera saw them)")
    coverage = seen | filled  # the texels that hold a sample's maps, measured or filled
    model_y = chans["model"]["Y"]
    off = coverage & (np.abs(model_y - np.rint(model_y)) > 1e-3)
    if np.any(off):
        raise ImageFormatError(f"{folder / 'model.exr'}: model indices must be integers (rungs of the ladder); "
                               f"{int(off.sum())} covered texel(s) are not, e.g. {float(model_y[off][0])!r}")
    model = np.rint(model_y).astype(np.int32)
    if np.any((model[coverage] < 0) | (model[coverage] >= len(MODELS))):
        raise ImageFormatError(f"{folder / 'model.exr'}: model indices must be in 0..{len(MODELS) - 1} "
                               f"({', '.join(MODELS)})")
    alpha = st("roughness", ("alpha_x", "alpha_y"))
    if np.any(alpha[coverage] <= 0):
        raise ImageFormatError(f"{folder / 'roughness.exr'}: alpha must be > 0 on covered texels")
    tex = TextureSet(
        albedo=st("albedo", "RGB"),
        specular=st("specular", ("Y",)),
        alpha=alpha,
        normal=st("normal", ("world.R", "world.G", "world.B")),
        tangent=st("normal", ("tangent.R", "tangent.G", "tangent.B")),
        normal_ts=2.0 * st("normal", "RGB") - 1.0,
        mfp=st("mean_free_path", "RGB"),
        model=model,
        coverage=seen,
        info=info,
        filled=filled,
    )
    if rs is not None:
        with set_refusal_as(folder):
            if isinstance(rs, ResultSetError):
                raise rs
            rs.check(SET_FILES)
    return tex, tex.surface_info


def _open_set(folder: Path):
    """The folder's result set, or the ResultSetError opening it gave (raised after the content checks)."""
    try:
        return open_result_set(folder)
    except ResultSetError as err:
        return err
