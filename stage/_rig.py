"""Light rigs: where the lights are, how bright they are, and the solid angle
each one stands for.

Units: positions in millimetres in the stage frame (x right, y up, z toward
the main camera; the rig centre is the origin). A near-field light is an
isotropic point source of radiant intensity I [W sr^-1 per channel]: the
irradiance it delivers at normal incidence at a point p is I / |x - p|^2
(inverse-square law). A distant light delivers the irradiance E = intensity
[W m^-2 per channel] at every point, from one direction.
"""

from __future__ import annotations

import json
from importlib import resources

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from scipy.spatial import SphericalVoronoi

from brdf import safe_normalize

# Two lights closer than this (as directions from the centre) cannot be told
# apart by a Voronoi partition; scipy's construction also breaks down there.
_COINCIDENT_RAD = 1e-6


def voronoi_solid_angles(directions: np.ndarray) -> np.ndarray:
    """Solid angle [sr] of each direction's spherical Voronoi cell (sums to 4 pi).

    directions: [L, 3] unit vectors. Uses scipy's SphericalVoronoi (Caroli et al.
    2009) on the unit sphere.
    """
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"rig directions must have shape [L, 3], got {d.shape}")
    if d.shape[0] < 4:
        raise ValueError(f"a spherical Voronoi partition needs at least 4 lights, got {d.shape[0]}")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    gram = d @ d.T
    np.fill_diagonal(gram, -1.0)
    i, j = np.unravel_index(np.argmax(gram), gram.shape)
    if gram[i, j] > np.cos(_COINCIDENT_RAD):
        raise ValueError(f"rig has coincident lights: lights {i} and {j} point the same way")
    sv = SphericalVoronoi(d, radius=1.0, center=np.zeros(3))
    return sv.calculate_areas()


class Rig(eqx.Module):
    """A set of lights around the rig centre.

    Fields: ``position`` [L, 3] mm (for distant lights, the unit direction times
    ``radius``), ``intensity`` [L, C] (radiant intensity for near-field lights,
    irradiance at normal incidence for distant ones), ``solid_angle`` [L] sr of
    each light's spherical Voronoi cell as seen from the centre, and
    ``near_field`` (static).
    """

    position: Float[Array, "light 3"]
    intensity: Float[Array, "light channel"]
    solid_angle: Float[Array, " light"]
    near_field: bool = eqx.field(static=True, default=True)

    def __check_init__(self):
        if self.position.ndim != 2 or self.position.shape[-1] != 3 or self.position.shape[0] == 0:
            raise ValueError(f"Rig.position must have shape [L, 3] with L >= 1, got {self.position.shape}")
        if self.intensity.shape[0] != self.position.shape[0] or self.intensity.ndim != 2:
            raise ValueError(
                f"Rig.intensity must have shape [L, C] with L = {self.position.shape[0]}, got {self.intensity.shape}"
            )

    @property
    def num_lights(self) -> int:
        return self.position.shape[0]

    @property
    def directions(self) -> Float[Array, "light 3"]:
        """Unit vectors from the rig centre toward each light."""
        return safe_normalize(self.position)

    @property
    def center_irradiance(self) -> Float[Array, "light channel"]:
        """Irradiance each light delivers at the rig centre at normal incidence."""
        if not self.near_field:
            return self.intensity
        d2 = jnp.sum(self.position**2, axis=-1, keepdims=True)
        return self.intensity / d2

    def incident(
        self, points: Float[Array, "*batch 3"]
    ) -> tuple[Float[Array, "light *batch 3"], Float[Array, "light *batch channel"]]:
        """World direction toward each light and the irradiance at normal incidence
        it delivers at each point (inverse-square law for near-field lights)."""
        points = jnp.asarray(points)
        extra = (1,) * (points.ndim - 1)
        pos = self.position.reshape((-1,) + extra + (3,))
        inten = self.intensity.reshape((-1,) + extra + (self.intensity.shape[-1],))
        if self.near_field:
            delta = pos - points[None]
            d2 = jnp.sum(delta * delta, axis=-1, keepdims=True)
            return safe_normalize(delta), inten / d2
        wi = jnp.broadcast_to(safe_normalize(pos), (self.num_lights,) + points.shape)
        irr = jnp.broadcast_to(inten, (self.num_lights,) + points.shape[:-1] + (inten.shape[-1],))
        return wi, irr

    def subset(self, index) -> "Rig":
        """The rig restricted to the lights ``index`` (solid angles recomputed)."""
        index = np.asarray(index)
        pos = np.asarray(self.position)[index]
        return Rig(
            position=jnp.asarray(pos),
            intensity=jnp.asarray(np.asarray(self.intensity)[index]),
            solid_angle=jnp.asarray(voronoi_solid_angles(pos), dtype=self.solid_angle.dtype),
            near_field=self.near_field,
        )


def make_rig(position, intensity=1.0, near_field: bool = True, channels: int = 3) -> Rig:
    """A rig from light positions [L, 3] (mm; directions for distant lights) with
    Voronoi solid angles; ``intensity`` is a scalar, [L] or [L, C]."""
    pos = np.asarray(position, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"light positions must have shape [L, 3], got {pos.shape}")
    if pos.shape[0] == 0:
        raise ValueError("a rig needs at least one light; got none")
    if not np.all(np.isfinite(pos)):
        raise ValueError("light positions contain NaN or Inf")
    r = np.linalg.norm(pos, axis=1)
    if np.any(r <= 0):
        raise ValueError(f"light {int(np.argmin(r))} sits at the rig centre; lights need a direction")
    inten = np.asarray(intensity, dtype=np.float64)
    if inten.ndim == 0:
        inten = np.full((pos.shape[0], channels), float(inten))
    elif inten.ndim == 1:
        inten = np.repeat(inten[:, None], channels, axis=1)
    if inten.shape[0] != pos.shape[0]:
        raise ValueError(f"intensity has {inten.shape[0]} rows for {pos.shape[0]} lights")
    if np.any(inten < 0) or not np.all(np.isfinite(inten)):
        raise ValueError("light intensities must be finite and non-negative")
    omega = voronoi_solid_angles(pos)
    return Rig(
        position=jnp.asarray(pos, dtype=jnp.float32),
        intensity=jnp.asarray(inten, dtype=jnp.float32),
        solid_angle=jnp.asarray(omega, dtype=jnp.float32),
        near_field=near_field,
    )


def _icosphere(subdivisions: int) -> np.ndarray:
    t = (1.0 + 5**0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in v]
    faces = list(f)
    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}

        def mid(a, b):
            k = (min(a, b), max(a, b))
            if k not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[k] = len(verts) - 1
            return cache[k]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.stack(verts)


def geodesic_dome(subdivisions: int = 2, radius_mm: float = 1000.0, near_field: bool = False,
                  irradiance: float = 1.0) -> Rig:
    """Lights at the vertices of a subdivided icosahedron (10 * 4^s + 2 lights).

    Distant lights by default, each delivering ``irradiance`` at normal
    incidence; with ``near_field`` they are point sources at ``radius_mm`` whose
    intensity gives that irradiance at the centre.
    """
    if subdivisions < 0:
        raise ValueError(f"subdivisions must be >= 0, got {subdivisions}")
    dirs = _icosphere(int(subdivisions))
    inten = irradiance * (radius_mm**2 if near_field else 1.0)
    return make_rig(dirs * radius_mm, inten, near_field=near_field)


_LSX_DUPLICATE_ROW = 321  # 0-based index of row 322
_LSX_DUPLICATED_ROW = 196
_LSX_ORIGINAL_VALUE_CM = (0.00, -97.43, 89.52)


def _lsx_table() -> dict:
    with resources.files("stage.data").joinpath("light_stage_x.json").open("r") as fh:
        return json.load(fh)


def light_stage_x(ordering: str = "all", intensity: float | None = None) -> Rig:
    """The ICT Light Stage X: 346 near-field lights, radius ~1.32 m (bundled table;
    positions transcribed from dreamworksanimation/moonray, Apache-2.0).

    ordering: "all" (346 lights in table order), "polarized" (85) or
    "unpolarized" (201), the stage's own one-light-at-a-time orderings.
    intensity: radiant intensity of every light; by default the value that gives
    irradiance 1 at the centre from a light at the mean radius.
    """
    table = _lsx_table()
    pos_cm = np.asarray(table["positions_cm"], dtype=np.float64)
    # Row 322 (1-based) of the transcribed table duplicates row 197 (a light
    # behind the head), which leaves a hole in front-below and two coincident
    # lights. The table's upstream note gives the original value; it sits at
    # the rig's typical 10.7-degree spacing from its neighbours, so restore it.
    if np.allclose(pos_cm[_LSX_DUPLICATE_ROW], pos_cm[_LSX_DUPLICATED_ROW]):
        pos_cm[_LSX_DUPLICATE_ROW] = _LSX_ORIGINAL_VALUE_CM
    pos = pos_cm * 10.0
    if ordering == "polarized":
        pos = pos[np.asarray(table["order_polarized"]) - 1]
    elif ordering == "unpolarized":
        pos = pos[np.asarray(table["order_unpolarized"]) - 1]
    elif ordering != "all":
        raise ValueError(f"ordering must be 'all', 'polarized' or 'unpolarized', got {ordering!r}")
    if intensity is None:
        intensity = float(np.mean(np.sum(pos**2, axis=1)))
    return make_rig(pos, intensity, near_field=True)
