"""Per-sample material maps: what a fit produces and what rendering, the
texture-set writer and the CLI consume.

One type for every rung of the model ladder (``MODELS``), so that a map set
can mix models per sample (``model`` map) and still be evaluated with one
vectorised BRDF (:class:`LadderBRDF`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

import brdf
import stage
from brdf import phong_exponent as phong_exponent  # brdf's one formula, re-exported (relight.phong_exponent)
from brdf import safe_normalize

# The model ladder, simplest first; each rung adds to the one before it.
MODELS = ("lambert", "blinn_phong", "ggx", "ggx_aniso", "subsurface")
LAMBERT, BLINN_PHONG, GGX, GGX_ANISO, SUBSURFACE = range(len(MODELS))

# Valid ranges of the maps (checked by MaterialMaps and material_maps, so a
# map set read from files is checked too). Albedos are fractions of energy:
# rho_d (Lambert albedo, or a profile's total diffuse reflectance) and rho_s
# (Schlick F0, or the Blinn-Phong lobe's albedo) in [0, 1]. GGX alpha in
# (0, ALPHA_MAX]: alpha = 1 is already a nearly uniform lobe, the fitter's
# upper bound, and no fitted or bundled map exceeds it (brdf clamps the lower
# end at brdf.ALPHA_MIN = 1e-4 when evaluating). RANGE_TOL absorbs float32
# rounding of values at a bound (a sigmoid at 1, a blend of two 1s).
ALPHA_MAX = 1.0
RANGE_TOL = 1e-6
# Normals shorter than this carry no direction (an unset or zeroed texel).
_MIN_NORMAL = 1e-6


class LadderBRDF(brdf.AbstractBRDF):
    """The BRDF of a material-map set in each sample's local frame:

        f_r = rho_d / pi * [model < SUBSURFACE]
              + rho_s (s + 8) / (8 pi) cos(theta_h)^s           (model = BLINN_PHONG, s = phong_exponent(alpha_x))
              + D_GGX(alpha_x, alpha_y) F_Schlick(rho_s) G / (4 cos_i cos_o)  (model >= GGX)

    composed from brdf's kernels and Modules (``brdf.blinn_phong_lobe``,
    ``brdf.phong_exponent``; ``brdf.Microfacet(GGX, SchlickFresnel, "smith")``).

    For ``SUBSURFACE`` samples the diffuse term is left out: that light leaves
    through the diffusion profile (see :meth:`MaterialMaps.profile`). Set
    ``include_diffuse=True`` to keep it as a local Lambert term instead (the
    zero-mean-free-path limit)."""

    rho_d: Float[Array, "*batch 3"]
    rho_s: Float[Array, "*batch 1"]
    alpha: Float[Array, "*batch 2"]
    model: Int[Array, "*batch 1"]
    include_diffuse: bool = eqx.field(static=True, default=False)

    def __call__(self, wi, wo):
        """f_r in 1/sr, shape [..., 3]; 0 below the horizon."""
        active = (wi[..., 2:3] > 0) & (wo[..., 2:3] > 0)
        model = self.model
        diffuse_on = (model < SUBSURFACE) | self.include_diffuse
        diffuse = jnp.where(diffuse_on, self.rho_d / jnp.pi, 0.0)
        ax, ay = self.alpha[..., 0:1], self.alpha[..., 1:2]
        ay = jnp.where(model >= GGX_ANISO, ay, ax)
        ggx = brdf.Microfacet(brdf.GGX(ax, ay), brdf.SchlickFresnel(self.rho_s), "smith")(wi, wo)
        cos_h = safe_normalize(wi + wo)[..., 2:3]
        phong = brdf.blinn_phong_lobe(cos_h, self.rho_s, phong_exponent(ax))
        spec = jnp.where(model >= GGX, ggx, jnp.where(model == BLINN_PHONG, phong, 0.0))
        return jnp.where(active, diffuse + spec, 0.0)

    def fittable(self) -> dict[str, brdf.ParamSpec]:
        """None: a map set is fitted by :func:`relight.fit`, rung by rung."""
        return {}


class MaterialMaps(eqx.Module):
    """Reflectance maps over P surface samples (texels or pixels).

    rho_d [P, 3]: diffuse albedo (for ``SUBSURFACE`` samples the total diffuse
    reflectance of the profile). rho_s [P, 1]: specular albedo (Schlick F0 for
    the GGX rungs, the lobe's albedo for Blinn-Phong). alpha [P, 2]: GGX
    roughness along the tangent and bitangent (equal unless anisotropic).
    normal, tangent [P, 3]: the fitted shading frame in world space (unit,
    orthogonal). mfp [P, 3]: diffuse mean free path in mm (Christensen & Burley
    2015's ``dmfp``; used where model = SUBSURFACE). model [P]: ladder rung
    (index into ``MODELS``).

    Valid values (checked at construction when the maps are concrete, i.e.
    not traced under jit / grad; ValueError naming the map and the count of
    bad samples): every map finite; rho_d, rho_s in [0, 1] and alpha in
    (0, ``ALPHA_MAX`` = 1] (to ``RANGE_TOL``); mfp >= 0; model an integer rung
    0..4; normal nonzero and tangent not parallel to it.
    :func:`material_maps` also makes the normals unit and the tangents
    orthogonal to them."""

    rho_d: Float[Array, "sample 3"]
    rho_s: Float[Array, "sample 1"]
    alpha: Float[Array, "sample 2"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    mfp: Float[Array, "sample 3"]
    model: Int[Array, " sample"]

    def __check_init__(self):
        values = _concrete_maps(self)
        # Wrong shapes are reported by the consumers that know the sample count (relight.render.check_inputs).
        if values is not None and _documented_shapes(values):
            _check_values("MaterialMaps", *values)

    @property
    def num_samples(self) -> int:
        return self.rho_d.shape[0]

    def brdf(self, include_diffuse: bool = False) -> LadderBRDF:
        """The per-sample BRDF (leading sample axis) in the frame of :meth:`frame`."""
        return LadderBRDF(self.rho_d, self.rho_s, self.alpha, self.model[:, None], include_diffuse)

    def frame(self, surface: stage.Surface) -> stage.Surface:
        """``surface`` with its shading frame replaced by the maps' (t, b = n x t, n)."""
        n = safe_normalize(jnp.asarray(self.normal, surface.normal.dtype))
        t = jnp.asarray(self.tangent, n.dtype)
        t = safe_normalize(t - jnp.sum(t * n, -1, keepdims=True) * n)
        b = jnp.cross(n, t)
        return eqx.tree_at(lambda s: (s.normal, s.tangent, s.bitangent), surface, (n, t, b))

    def profile(self):
        """Christensen & Burley 2015 diffusion profile per sample (albedo rho_d,
        diffuse mean free path mfp; parameters [P, 3]), for the diffusion operator."""
        import skin_bssrdf

        mfp = jnp.maximum(jnp.asarray(self.mfp), 1e-3)
        return skin_bssrdf.Burley.from_mean_free_path(jnp.clip(self.rho_d, 0.0, 1.0), mfp, config="dmfp")

    @property
    def has_subsurface(self) -> bool:
        return bool(np.any(np.asarray(self.model) == SUBSURFACE))


def material_maps(surface: stage.Surface, rho_d, rho_s=None, alpha=None, *, normal=None, tangent=None, mfp=None,
                  model=None) -> MaterialMaps:
    """Build and validate a ``MaterialMaps`` over a surface's samples.

    Args:
        surface: the samples the maps describe (P of them).
        rho_d: diffuse albedo [P, 3] (or broadcastable).
        rho_s: specular albedo [P] / [P, 1] (None: no specular, 0).
        alpha: roughness [P] / [P, 1] (isotropic) or [P, 2] (None: 0.3).
        normal: shading normals [P, 3] (None: the surface's own).
        tangent: shading tangents [P, 3] (None: the surface's own).
        mfp: diffuse mean free path (mm) [P, 3] (None: 0).
        model: the per-sample model index (None: GGX where rho_s is given and positive somewhere, GGX_ANISO if
            alpha also has two distinct columns, LAMBERT otherwise).

    Returns:
        The ``MaterialMaps``.
    """
    P = surface.num_samples
    f = lambda x, c, name: _per_sample(x, P, c, name)  # noqa: E731
    rho_d = f(rho_d, 3, "rho_d")
    rho_s = f(0.0 if rho_s is None else rho_s, 1, "rho_s")
    a = np.asarray(0.3 if alpha is None else alpha, np.float64)
    if a.ndim == 2 and a.shape[-1] == 2:
        alpha2 = f(a, 2, "alpha")
    else:
        alpha2 = np.repeat(f(a, 1, "alpha"), 2, axis=1)
    normal = f(surface.normal if normal is None else normal, 3, "normal")
    tangent = f(surface.tangent if tangent is None else tangent, 3, "tangent")
    mfp = f(0.0 if mfp is None else mfp, 3, "mfp")
    if model is None:
        aniso = np.any(np.abs(alpha2[:, 0] - alpha2[:, 1]) > 1e-6 * alpha2[:, 0])
        default = LAMBERT if rho_s is None or not np.any(rho_s > 0) else (GGX_ANISO if aniso else GGX)
        model = np.full(P, default, np.int32)
    m = np.asarray(model)
    try:
        m = np.broadcast_to(m, (P,))
    except ValueError:
        raise ValueError(f"material_maps: model must broadcast to [{P}], got shape {m.shape}") from None
    _check_values("material_maps", rho_d, rho_s, alpha2, normal, tangent, mfp, m)
    # Unit normals and tangents orthogonal to them, as the type documents; rows
    # that already are (to float32 rounding) are left bit for bit as given.
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(np.abs(length - 1.0) > 1e-6, normal / length, normal)
    t_perp = tangent - np.sum(tangent * normal, 1, keepdims=True) * normal
    t_unit = t_perp / np.linalg.norm(t_perp, axis=1, keepdims=True)
    off = np.any(np.abs(t_unit - tangent) > 1e-6, axis=1, keepdims=True)
    tangent = np.where(off, t_unit, tangent)
    dt = jnp.asarray(surface.position).dtype
    j = lambda x: jnp.asarray(x, dt)  # noqa: E731
    return MaterialMaps(j(rho_d), j(rho_s), j(alpha2), j(normal), j(tangent), j(mfp), jnp.asarray(m, jnp.int32))


def _concrete_maps(maps: MaterialMaps):
    """The maps as NumPy arrays, or None when any is traced (under jit / grad)."""
    try:
        return tuple(np.asarray(getattr(maps, k)) for k in ("rho_d", "rho_s", "alpha", "normal", "tangent", "mfp",
                                                             "model"))
    except Exception:  # a tracer: values unknown until run
        return None


def _documented_shapes(values) -> bool:
    rho_d, rho_s, alpha, normal, tangent, mfp, model = values
    P = rho_d.shape[0] if rho_d.ndim else -1
    want = ((P, 3), (P, 1), (P, 2), (P, 3), (P, 3), (P, 3), (P,))
    return all(tuple(v.shape) == w for v, w in zip(values, want, strict=True))


def _bad(where: str, name: str, what: str, bad: np.ndarray, values: np.ndarray | None = None) -> None:
    """Raise ValueError naming the map, the rule and the count of bad samples."""
    rows = np.flatnonzero(np.any(bad.reshape(bad.shape[0], -1), axis=1)) if bad.ndim else np.zeros(0, int)
    if len(rows) == 0:
        return
    seen = ""
    if values is not None:
        v = np.asarray(values, np.float64)[bad]
        seen = f"; found {v.min():.4g} .. {v.max():.4g}" if v.size else ""
    raise ValueError(f"{where}: {name} {what}; {len(rows)} of {bad.shape[0]} sample(s) are not "
                     f"(first: {rows[:5].tolist()}){seen}")


def _check_values(where, rho_d, rho_s, alpha, normal, tangent, mfp, model) -> None:
    """The checks of the MaterialMaps docstring, on NumPy arrays."""
    maps = {"rho_d (diffuse albedo)": rho_d, "rho_s (specular albedo, Schlick F0)": rho_s,
            "alpha (GGX roughness)": alpha, "normal": normal, "tangent": tangent, "mfp (mean free path)": mfp}
    arrays = {}
    for name, x in maps.items():
        x = np.asarray(x, np.float64)
        _bad(where, name, "must be finite (no NaN or Inf)", ~np.isfinite(x))
        arrays[name.split(" ")[0]] = x
    lo, hi = -RANGE_TOL, 1.0 + RANGE_TOL
    for name in ("rho_d (diffuse albedo)", "rho_s (specular albedo, Schlick F0)"):
        x = arrays[name.split(" ")[0]]
        _bad(where, name, "must be in [0, 1]", (x < lo) | (x > hi), x)
    a = arrays["alpha"]
    _bad(where, "alpha (GGX roughness)", f"must be in (0, {ALPHA_MAX:g}]", (a <= 0) | (a > ALPHA_MAX + RANGE_TOL), a)
    _bad(where, "mfp (mean free path)", "must be >= 0 (mm)", arrays["mfp"] < 0, arrays["mfp"])
    m = np.asarray(model)
    mf = m.astype(np.float64)
    bad = ~np.isfinite(mf) | (mf != np.round(mf)) | (mf < 0) | (mf > len(MODELS) - 1)
    _bad(where, "model", f"must be an integer rung of the ladder 0..{len(MODELS) - 1} ({', '.join(MODELS)})",
         bad, mf)
    n = arrays["normal"]
    length = np.linalg.norm(n, axis=1)
    _bad(where, "normal", "must be nonzero (a unit direction; zero-length normals have none)",
         length < _MIN_NORMAL)
    t = arrays["tangent"]
    t_perp = t - np.sum(t * n, 1, keepdims=True) * n / np.maximum(length, _MIN_NORMAL)[:, None] ** 2
    _bad(where, "tangent", "must be nonzero and not parallel to the normal",
         np.linalg.norm(t_perp, axis=1) < _MIN_NORMAL * np.maximum(np.linalg.norm(t, axis=1), 1.0))


def _per_sample(x, P, c, name):
    x = np.asarray(x, np.float64)
    if x.ndim == 1 and c == 1 and x.shape[0] == P:
        x = x[:, None]
    try:
        out = np.broadcast_to(x, (P, c)).copy()
    except ValueError:
        raise ValueError(f"material_maps: {name} must broadcast to [{P}, {c}], got shape {x.shape}") from None
    if not np.all(np.isfinite(out)):
        raise ValueError(f"material_maps: {name} has NaN or Inf")
    return out
