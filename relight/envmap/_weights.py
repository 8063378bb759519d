"""Environment map -> light-stage light weights.

Image-based relighting (Debevec et al. 2000, "Acquiring the Reflectance Field
of a Human Face", SIGGRAPH 2000) writes the subject under an environment as a
weighted sum of its one-light-at-a-time images:

    relit[p, c] = sum_l  w[l, c] * OLAT_l[p, c]

where OLAT_l was captured with light l delivering irradiance ``E_l[c]`` at the
rig centre at normal incidence, and

    w[l, c] = ( integral over light l's cell of L_env(d)[c] dOmega ) / E_l[c].

The cells partition the sphere, so ``sum_l w[l] E_l`` equals the integral of
the map over the sphere: no energy is lost or invented. Two partitions:

* :func:`light_weights` -- spherical Voronoi cells (each direction goes to its
  nearest light). Exact for the piecewise-constant map: every pixel (or each
  of its ``supersample**2`` sub-pixels, with their exact solid angles) is
  assigned whole to one light. Every light reproduces the light it stands for;
  a small bright source (the sun) lands on one light, so as the environment
  rotates the sun hops from light to light (popping shadows).
* :func:`light_weights_barycentric` -- each direction's radiance is shared
  between the three lights of the rig triangle containing it, in proportion to
  its (gnomonic) barycentric coordinates. Weights vary continuously with the
  environment: a moving sun cross-fades between neighbouring lights instead of
  hopping, at the price of turning one hard shadow into up to three fainter
  ones, and of a slight blur (one light spacing) of all lighting.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from brdf import widest_float

from ._latlong import EnvMap, latlong_directions, latlong_solid_angles

__all__ = [
    "light_weights",
    "light_weights_barycentric",
    "rig_triangulation",
    "rotation_sweep_weights",
    "voronoi_cell_integrals",
    "barycentric_cell_integrals",
]

# Sub-pixel samples per block when assigning map samples to lights: the
# [block, L] score matrix is the peak memory (8192 x 346 x 8 B ~ 23 MB).
_BLOCK = 8192


def _check_rig(env: EnvMap, directions, irradiance):
    directions = jnp.asarray(directions)
    if directions.ndim != 2 or directions.shape[1] != 3 or directions.shape[0] == 0:
        raise ValueError(f"light directions must be [L, 3] unit vectors, got shape {directions.shape}")
    if irradiance is not None:
        irradiance = jnp.asarray(irradiance)
        c = env.radiance.shape[-1]
        if irradiance.ndim == 1:
            irradiance = jnp.broadcast_to(irradiance[:, None], (irradiance.shape[0], c))
        if irradiance.shape != (directions.shape[0], c):
            raise ValueError(
                f"light irradiance must be [L, C] = {(directions.shape[0], c)} to match {directions.shape[0]} "
                f"light directions and the map's {c} channels, got shape {irradiance.shape}"
            )
    return directions, irradiance


def _present(irradiance) -> np.ndarray | None:
    """bool [L]: the lights that can relight (positive irradiance in every
    channel); None when ``irradiance`` is traced (under jit), where it cannot
    be inspected. A light of zero irradiance in every channel is absent: its
    OLAT image holds no signal, so it takes no part in the partition (its
    weight is 0 and its directions go to the nearest present lights, so no
    energy is lost). Raises ValueError on a negative or non-finite irradiance,
    a light zero in some channels only, and a rig with no positive light."""
    try:
        e = np.asarray(irradiance, np.float64)
    except Exception:  # a tracer: the weights guard the division instead
        return None
    bad = np.flatnonzero(~np.all(np.isfinite(e) & (e >= 0), axis=-1))
    if len(bad):
        raise ValueError(f"light irradiance must be finite and >= 0; light(s) {bad[:8].tolist()} are not")
    zero, positive = np.all(e == 0, axis=-1), np.all(e > 0, axis=-1)
    mixed = np.flatnonzero(~zero & ~positive)
    if len(mixed):
        raise ValueError(f"light irradiance must be positive in every channel or zero in all (an absent light); "
                         f"light(s) {mixed[:8].tolist()} are zero in some channels only")
    if not positive.any():
        raise ValueError(f"light irradiance is zero for all {len(e)} lights: a rig with no positive light cannot "
                         "relight")
    return positive


def _divide(integrals: Array, irradiance: Array) -> Array:
    """integrals / irradiance, 0 where the irradiance is not positive (a guard
    for traced rigs, whose absent lights ``_present`` cannot see)."""
    e = irradiance.astype(integrals.dtype)
    ok = e > 0
    return jnp.where(ok, integrals / jnp.where(ok, e, 1.0), 0.0)


def _scatter(part: Array, index: np.ndarray, n_lights: int) -> Array:
    """[L, C] with rows ``index`` from ``part`` and 0 elsewhere."""
    return jnp.zeros((n_lights,) + part.shape[1:], part.dtype).at[index].set(part)


def _supersampled(env: EnvMap, supersample: int, dt):
    """Sub-pixel directions [N, 3], their exact solid angles [N] and radiance [N, C]."""
    h, w, c = env.radiance.shape
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be a positive integer, got {supersample}")
    dirs = latlong_directions(h * s, w * s, dt).reshape(-1, 3)
    dom = latlong_solid_angles(h * s, w * s, dt).reshape(-1)
    rad = env.radiance.astype(dt)
    if s > 1:
        rad = jnp.repeat(jnp.repeat(rad, s, axis=0), s, axis=1)
    return dirs, dom, rad.reshape(-1, c)


def _blocks(n: int) -> tuple[int, int]:
    block = min(_BLOCK, n)
    return block, (-n) % block


def voronoi_cell_integrals(
    env: EnvMap, directions: Float[ArrayLike, "L 3"], supersample: int = 1
) -> Float[Array, "L C"]:
    """Radiance integrated over each light's spherical Voronoi cell, int_cell L dOmega.

    Every (sub-)pixel goes to its nearest light: the largest d . light (the geodesic nearest for unit vectors).
    The sum over lights equals ``envmap_integral`` up to rounding.

    Args:
        env: lat-long environment map (radiance [H, W, C]).
        directions: unit vectors [L, 3] from the rig centre toward each light, in the map's frame (x right,
            y up, z toward the camera).
        supersample: each map pixel is split into s x s sub-pixels (exact sub-pixel solid angles) before
            assignment; energy conservation holds for any s.

    Returns:
        Radiance x sr, [L, C].

    References:
        Debevec et al. 2000, "Acquiring the reflectance field of a human face" (the lights' cells of the sphere).
    """
    directions, _ = _check_rig(env, directions, None)
    return _voronoi_jit(env, directions, int(supersample))


@functools.partial(jax.jit, static_argnums=2)
def _voronoi_jit(env: EnvMap, directions: Array, supersample: int) -> Array:
    # jit here (not only at the caller) so eager calls reuse the compiled scan.
    dt = widest_float(env.radiance.dtype, directions.dtype, jnp.float32)
    dirs, dom, rad = _supersampled(env, supersample, dt)
    n_lights = directions.shape[0]
    unit = directions.astype(dt)
    unit = unit / jnp.linalg.norm(unit, axis=-1, keepdims=True)
    block, pad = _blocks(dirs.shape[0])
    contrib = rad * dom[:, None]
    dirs_b = jnp.concatenate([dirs, jnp.zeros((pad, 3), dt)]).reshape(-1, block, 3)
    contrib_b = jnp.concatenate([contrib, jnp.zeros((pad, contrib.shape[1]), dt)]).reshape(-1, block, contrib.shape[1])

    def step(acc, xs):
        d, cb = xs
        # float32 is enough to pick the owner (a pixel within rounding of a
        # cell boundary may go either way; energy is conserved regardless).
        idx = jnp.argmax(d @ unit.T.astype(jnp.float32), axis=-1)
        return acc + jax.ops.segment_sum(cb, idx, num_segments=n_lights), None

    acc0 = jnp.zeros((n_lights, contrib.shape[1]), dt)
    acc, _ = jax.lax.scan(step, acc0, (dirs_b.astype(jnp.float32), contrib_b))
    return acc


def light_weights(
    env: EnvMap,
    directions: Float[ArrayLike, "L 3"],
    irradiance: Float[ArrayLike, "L C"] | Float[ArrayLike, " L"],
    supersample: int = 1,
) -> Float[Array, "L C"]:
    """Per-light, per-channel weights for image-based relighting under ``env``,
    by spherical Voronoi cells (Debevec et al. 2000; see the module docstring).

    Args:
        env: lat-long environment map (radiance [H, W, C]).
        directions: unit vectors from the rig centre toward each light, in the
            map's frame (x right, y up, z toward the camera).
        irradiance: irradiance each light delivers at the rig centre at normal
            incidence when it is on alone (the OLAT capture's illumination),
            [L, C] or [L]; must be positive.
        supersample: each map pixel is split into ``s x s`` sub-pixels (exact
            sub-pixel solid angles) before assignment, so cell boundaries cut
            through pixels more finely; energy conservation holds for any s.

    Returns:
        ``w [L, C]`` (dimensionless) such that ``relit = sum_l w_l * OLAT_l`` and
        ``sum_l w_l * irradiance_l`` equals the map's integral over the sphere.

    A light whose irradiance is 0 in every channel is absent (its OLAT image is
    black): its weight is 0 and the cells are those of the present lights, so
    the energy identity still holds. Raises ValueError when no light is
    positive (a rig that cannot relight), or on a negative or non-finite
    irradiance, or one zero in some channels only. Never NaN or Inf.
    """
    directions, irradiance = _check_rig(env, directions, irradiance)
    present = _present(irradiance)
    if present is None or present.all():
        return _divide(voronoi_cell_integrals(env, directions, supersample), irradiance)
    keep = np.flatnonzero(present)
    part = voronoi_cell_integrals(env, directions[keep], supersample)
    return _scatter(_divide(part, irradiance[keep]), keep, directions.shape[0])


def rig_triangulation(directions: Float[ArrayLike, "L 3"]) -> Int[np.ndarray, "F 3"]:
    """Outward-facing triangles of the convex hull of the light directions (scipy's Qhull).

    The spherical triangulation the barycentric weights use.

    Args:
        directions: unit vectors [L, 3] toward each light; concrete (not traced).

    Returns:
        Light index triples [F, 3] (NumPy).
    """
    from scipy.spatial import ConvexHull

    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    hull = ConvexHull(d)
    faces = hull.simplices.copy()
    # Orient each face so its normal points away from the origin.
    v0, v1, v2 = d[faces[:, 0]], d[faces[:, 1]], d[faces[:, 2]]
    flip = np.einsum("ij,ij->i", np.cross(v1 - v0, v2 - v0), v0 + v1 + v2) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def barycentric_cell_integrals(
    env: EnvMap,
    directions: Float[ArrayLike, "L 3"],
    faces: Int[ArrayLike, "F 3"] | None = None,
    supersample: int = 1,
) -> Float[Array, "L C"]:
    """Radiance integrated against each light's spherical barycentric hat function, radiance x sr.

    A direction d inside triangle (a, b, c) has coordinates lambda = M^-1 d with M = [a b c] (its gnomonic
    barycentric coordinates once normalised to sum to 1); its radiance x solid angle is split between a, b, c in
    those proportions, so the hats sum to 1 and total energy is conserved exactly. The containing triangle is the
    hull facet the ray from the centre along d leaves through. For a rig that does not surround the centre (a
    hemisphere), directions below it fall on facets through or behind the centre; their negative coordinates are
    clipped and the rest renormalised, which still conserves energy.

    Args:
        env: lat-long environment map (radiance [H, W, C]).
        directions: unit vectors [L, 3] from the rig centre toward each light, in the map's frame (x right,
            y up, z toward the camera).
        faces: triangles [F, 3] of light indices (None: ``rig_triangulation(directions)``, which needs
            concrete directions).
        supersample: each map pixel is split into s x s sub-pixels (exact sub-pixel solid angles) before
            assignment; energy conservation holds for any s.

    Returns:
        Radiance x sr, [L, C].
    """
    directions, _ = _check_rig(env, directions, None)
    if faces is None:
        faces = rig_triangulation(directions)
    faces = jnp.asarray(faces, jnp.int32)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be [F, 3] light indices, got shape {faces.shape}")
    return _barycentric_jit(env, directions, faces, int(supersample))


@functools.partial(jax.jit, static_argnums=3)
def _barycentric_jit(env: EnvMap, directions: Array, faces: Array, supersample: int) -> Array:
    dt = widest_float(env.radiance.dtype, directions.dtype, jnp.float32)
    unit = directions.astype(dt)
    unit = unit / jnp.linalg.norm(unit, axis=-1, keepdims=True)
    n_lights = unit.shape[0]
    a, b, c = unit[faces[:, 0]], unit[faces[:, 1]], unit[faces[:, 2]]
    # M = [a b c] (columns, [F, 3(xyz), 3(vertex)]) inverted by Cramer's rule: rows b x c, c x a, a x b over
    # det M = a . (b x c). Not jnp.linalg.inv: a batched LAPACK call can hang XLA's CPU thread pool
    # (docs/fit.md, "Findings for the fitter", item 8).
    bc, ca, ab = jnp.cross(b, c), jnp.cross(c, a), jnp.cross(a, b)
    Minv = jnp.stack([bc, ca, ab], axis=1) / jnp.sum(a * bc, axis=-1)[:, None, None]  # [F, 3(vertex), 3(xyz)]
    # The ray from the centre along d leaves the hull through the facet whose
    # plane it meets first, i.e. the largest (n_f . d) / offset_f; offsets are
    # > 0 when the centre is inside the hull. Floor: a facet through the centre
    # (offset 0) must not divide by zero; it then ranks by n_f . d alone.
    normal = jnp.cross(b - a, c - a)
    offset = jnp.sum(normal * a, axis=-1)
    plane = normal / jnp.maximum(offset, 1e-12)[:, None]  # [F, 3]
    dirs, dom, rad = _supersampled(env, supersample, dt)
    contrib = rad * dom[:, None]
    block, pad = _blocks(dirs.shape[0])
    dirs_b = jnp.concatenate([dirs, jnp.zeros((pad, 3), dt)]).reshape(-1, block, 3)
    contrib_b = jnp.concatenate([contrib, jnp.zeros((pad, contrib.shape[1]), dt)]).reshape(-1, block, contrib.shape[1])

    def step(acc, xs):
        d, cb = xs
        best = jnp.argmax(d.astype(jnp.float32) @ plane.T.astype(jnp.float32), axis=-1)  # [block]
        lam = jnp.maximum(jnp.einsum("nvk,nk->nv", Minv[best], d), 0.0)  # [block, 3]
        total = jnp.sum(lam, axis=-1, keepdims=True)
        # total > 0 for every real direction (it lies in, or beside, its facet's
        # cone); padding rows (d = 0) carry zero contribution and get 1/3 each.
        ok = total > 0
        frac = jnp.where(ok, lam / jnp.where(ok, total, 1.0), 1.0 / 3.0)
        verts = faces[best]  # [block, 3]
        share = frac[:, :, None] * cb[:, None, :]  # [block, 3, C]
        acc = acc + jax.ops.segment_sum(share.reshape(-1, cb.shape[-1]), verts.reshape(-1), num_segments=n_lights)
        return acc, None

    acc0 = jnp.zeros((n_lights, contrib.shape[1]), dt)
    acc, _ = jax.lax.scan(step, acc0, (dirs_b, contrib_b))
    return acc


def light_weights_barycentric(
    env: EnvMap,
    directions: Float[ArrayLike, "L 3"],
    irradiance: Float[ArrayLike, "L C"] | Float[ArrayLike, " L"],
    faces: Int[ArrayLike, "F 3"] | None = None,
    supersample: int = 1,
) -> Float[Array, "L C"]:
    """Smooth per-light weights for image-based relighting: the map against each light's barycentric hat.

    The same convention and energy guarantee as ``light_weights`` (relit = sum_l w_l OLAT_l; sum_l w_l E_l is the
    map's integral), but continuous in the environment, which removes the shadow "popping" of a small bright
    source when the map is rotated. Absent lights (irradiance 0 in every channel) get weight 0 and the
    triangulation is that of the present lights (a given ``faces`` must then use present lights only); the same
    errors as ``light_weights``.

    Args:
        env: lat-long environment map (radiance [H, W, C]).
        directions: unit vectors [L, 3] from the rig centre toward each light, in the map's frame (x right,
            y up, z toward the camera).
        irradiance: irradiance each light delivers at the rig centre at normal incidence when on alone,
            [L, C] or [L]; >= 0, at least one light positive.
        faces: triangles [F, 3] of light indices (None: ``rig_triangulation(directions)``, which needs
            concrete directions).
        supersample: each map pixel is split into s x s sub-pixels (exact sub-pixel solid angles) before
            assignment; energy conservation holds for any s.

    Returns:
        Weights w [L, C] (dimensionless).

    References:
        Debevec et al. 2000, "Acquiring the reflectance field of a human face".
    """
    directions, irradiance = _check_rig(env, directions, irradiance)
    present = _present(irradiance)
    if present is None or present.all():
        return _divide(barycentric_cell_integrals(env, directions, faces, supersample), irradiance)
    keep = np.flatnonzero(present)
    if faces is not None:
        faces = np.asarray(faces)
        absent = np.setdiff1d(np.unique(faces), keep)
        if len(absent):
            raise ValueError(f"faces use light(s) {absent[:8].tolist()} of zero irradiance (absent lights): "
                             "triangulate the present lights only")
        faces = np.searchsorted(keep, faces)  # indices among the present lights
    part = barycentric_cell_integrals(env, directions[keep], faces, supersample)
    return _scatter(_divide(part, irradiance[keep]), keep, directions.shape[0])


def rotation_sweep_weights(
    env: EnvMap,
    directions: Float[ArrayLike, "L 3"],
    irradiance: Float[ArrayLike, "L C"] | Float[ArrayLike, " L"],
    rotations: Float[ArrayLike, "N 3 3"],
    method: str = "voronoi",
    faces: Int[ArrayLike, "F 3"] | None = None,
    supersample: int = 1,
) -> Float[Array, "N L C"]:
    """Light weights for the environment rotated by each of ``rotations`` (a turntable).

    Rotating the environment by R is the same as rotating the rig by R^T, so the map is never resampled: light l
    sees the map in direction R^T d_l. Feed the result to ``relight.render.relight_olat_sweep`` to relight all N
    rotations in one pass over the OLAT stack.

    Args:
        env: lat-long environment map (radiance [H, W, C]).
        directions: unit vectors [L, 3] from the rig centre toward each light, in the map's frame (x right,
            y up, z toward the camera).
        irradiance: irradiance each light delivers at the rig centre at normal incidence when on alone,
            [L, C] or [L]; >= 0, at least one light positive.
        rotations: rotation matrices [N, 3, 3] applied to the environment.
        method: ``"voronoi"`` (``light_weights``) or ``"barycentric"`` (``light_weights_barycentric``).
        faces: triangles [F, 3] of light indices (None: ``rig_triangulation(directions)``, which needs
            concrete directions). Barycentric only.
        supersample: each map pixel is split into s x s sub-pixels (exact sub-pixel solid angles) before
            assignment; energy conservation holds for any s.

    Returns:
        Weights [N, L, C].
    """
    if method not in ("voronoi", "barycentric"):
        raise ValueError(f"unknown light-weight method {method!r}; expected 'voronoi' or 'barycentric'")
    directions, irradiance = _check_rig(env, directions, irradiance)
    rotations = jnp.asarray(rotations)
    if rotations.ndim != 3 or rotations.shape[1:] != (3, 3):
        raise ValueError(f"rotations must be [N, 3, 3], got shape {rotations.shape}")
    if method == "barycentric" and faces is None:
        # Rotation does not change the triangulation: of the present lights only (light indices of the rig).
        present = _present(irradiance)
        keep = np.arange(directions.shape[0]) if present is None else np.flatnonzero(present)
        faces = keep[rig_triangulation(np.asarray(directions)[keep])]

    def one(R):
        rotated = directions @ R.astype(directions.dtype)  # rows: (R^T d_l)^T
        if method == "voronoi":
            return light_weights(env, rotated, irradiance, supersample)
        return light_weights_barycentric(env, rotated, irradiance, faces, supersample)

    return jax.lax.map(one, rotations)
