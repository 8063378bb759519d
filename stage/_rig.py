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
from jaxtyping import Array, ArrayLike, Float
from scipy.spatial import SphericalVoronoi, cKDTree

from brdf import fibonacci_sphere as brdf_fibonacci_sphere
from brdf import safe_normalize

from ._files import read_light_table
from ._forward import incident_light
from ._mesh import MAX_COORDINATE_MM

_FLOAT32_MAX = float(np.finfo(np.float32).max)

# Two lights closer than this (as directions from the centre) cannot be told
# apart by a Voronoi partition; scipy's construction also breaks down there.
_COINCIDENT_RAD = 1e-6
# The most lights a rig may have: 190 x the Light Stage X's 346, beyond any built stage or dome, and small enough
# that a rig's per-light arrays, its Voronoi partition and a capture's light axis stay bounded; a count from a
# user (``dome:N``, a rig file) is checked against it before anything is allocated.
MAX_LIGHTS = 65536


def check_light_count(n: int, where: str = "rig") -> int:
    """``n`` as an int when it is a light count a rig may have (1..``MAX_LIGHTS``); else ValueError naming
    ``where`` and the limit. Called before a rig's arrays are built, so a wrong count costs nothing."""
    n = int(n)
    if not 1 <= n <= MAX_LIGHTS:
        raise ValueError(f"{where}: {n} lights; a rig has 1 to {MAX_LIGHTS} (stage.MAX_LIGHTS)")
    return n


def voronoi_solid_angles(directions: np.ndarray) -> np.ndarray:
    """Solid angle of each direction's spherical Voronoi cell (scipy's SphericalVoronoi on the unit sphere).

    Args:
        directions: unit vectors [L, 3].

    Returns:
        Solid angles in sr, [L]; they sum to 4 pi.

    References:
        Caroli et al. 2009, "Robust and efficient Delaunay triangulations of points on or close to a sphere".
    """
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"rig directions must have shape [L, 3], got {d.shape}")
    if d.shape[0] < 4:
        raise ValueError(f"a spherical Voronoi partition needs at least 4 lights, got {d.shape[0]}")
    check_light_count(d.shape[0], "rig directions")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    # The closest pair by a k-d tree: O(L log L) time and O(L) memory (an L x L Gram matrix is 32 GB at 65536).
    dist, nearest = cKDTree(d).query(d, k=2)
    i = int(np.argmin(dist[:, 1]))
    j = int(nearest[i, 1] if nearest[i, 1] != i else nearest[i, 0])  # two at distance 0 may come in either order
    if dist[i, 1] < 2.0 * np.sin(_COINCIDENT_RAD / 2.0):  # the chord of _COINCIDENT_RAD
        i, j = min(i, j), max(i, j)
        raise ValueError(f"rig has coincident lights: lights {i} and {j} point the same way")
    # Lights on one great circle (a gonioreflectometer arc, a ring): the Voronoi
    # cells are lunes from pole to pole, of area 2 x their angular width.
    _, sing, vt = np.linalg.svd(d, full_matrices=False)
    if sing[-1] < 1e-9 * sing[0]:
        return _great_circle_solid_angles(d, vt[-1])
    sv = SphericalVoronoi(d, radius=1.0, center=np.zeros(3))
    return sv.calculate_areas()


def _great_circle_solid_angles(d: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Lune areas 2 * (angular width) of directions lying on the great circle normal to ``axis``."""
    e1 = d[0] - axis * (d[0] @ axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi = np.mod(np.arctan2(d @ e2, d @ e1), 2 * np.pi)
    order = np.argsort(phi)
    ps = phi[order]
    gap_next = np.diff(np.concatenate([ps, ps[:1] + 2 * np.pi]))
    gap_prev = np.roll(gap_next, 1)
    width = np.empty_like(phi)
    width[order] = 0.5 * (gap_next + gap_prev)
    return 2.0 * width


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
        check_light_count(self.position.shape[0], "Rig.position")
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
        self, points: Float[ArrayLike, "*batch 3"]
    ) -> tuple[Float[Array, "light *batch 3"], Float[Array, "light *batch channel"]]:
        """World direction toward each light and the irradiance at normal incidence
        it delivers at each point (inverse-square law for near-field lights):
        ``stage.incident_light`` of this rig's fields."""
        return incident_light(self.position, self.intensity, self.near_field, points)

    def subset(self, index) -> Rig:
        """The rig restricted to the lights ``index`` (solid angles recomputed)."""
        index = np.asarray(index)
        pos = np.asarray(self.position)[index]
        return Rig(
            position=jnp.asarray(pos),
            intensity=jnp.asarray(np.asarray(self.intensity)[index]),
            solid_angle=jnp.asarray(voronoi_solid_angles(pos), dtype=self.solid_angle.dtype),
            near_field=self.near_field,
        )


def make_rig(position, intensity=1.0, near_field: bool = True, channels: int = 3, calibration=None) -> Rig:
    """A rig from light positions, with each light's Voronoi solid angle.

    Args:
        position: light positions [L, 3] (mm; directions for distant lights).
        intensity: radiant intensity (near field) or irradiance (distant): a scalar, [L] or [L, C].
        near_field: point sources (True) or distant lights (False).
        channels: colour channels C.
        calibration: optional unitless gains (scalar, [C] or [L, C]) multiplying the intensities: the per-light RGB
            calibration a light stage measures with a colour chart or a white sphere (see ``calibrate``).

    Returns:
        The ``Rig``.

    Raises:
        ValueError: no lights, a light at the centre, coincident lights, or negative values.
    """
    pos = np.asarray(position, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"make_rig: argument 'position': light positions must have shape [L, 3], got {pos.shape}")
    if pos.shape[0] == 0:
        raise ValueError("make_rig: argument 'position': a rig needs at least one light; got none")
    if not np.all(np.isfinite(pos)):
        raise ValueError("make_rig: argument 'position': light positions contain NaN or Inf")
    if np.abs(pos).max() > MAX_COORDINATE_MM:
        raise ValueError(f"make_rig: argument 'position': a coordinate is {np.abs(pos).max():.3g} mm, beyond "
                         f"{MAX_COORDINATE_MM:.0e} mm (stage.MAX_COORDINATE_MM): wrong units?")
    r = np.linalg.norm(pos, axis=1)
    if np.any(r <= 0):
        raise ValueError(f"make_rig: argument 'position': light {int(np.argmin(r))} sits at the rig centre; "
                         "lights need a direction")
    inten = np.asarray(intensity, dtype=np.float64)
    if inten.ndim == 0:
        inten = np.full((pos.shape[0], channels), float(inten))
    elif inten.ndim == 1:
        inten = np.repeat(inten[:, None], channels, axis=1)
    if inten.ndim != 2 or inten.shape[0] != pos.shape[0]:
        raise ValueError(f"make_rig: argument 'intensity' has shape {inten.shape} for {pos.shape[0]} lights "
                         "(scalar, [L] or [L, C])")
    _check_intensities(inten, "make_rig's argument 'intensity'")
    if calibration is not None:
        inten = inten * _calibration_array(calibration, inten.shape)
        _check_intensities(inten, "make_rig's argument 'intensity' times 'calibration'")
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

        def mid(a, b, cache=cache):
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

    Args:
        subdivisions: s, the icosahedron's subdivision level (0: 12 lights, 1: 42, 2: 162, 3: 642).
        radius_mm: the dome's radius (mm), for near-field lights.
        near_field: point sources at ``radius_mm`` whose intensity gives ``irradiance`` at the centre (True), or
            distant lights each delivering ``irradiance`` at normal incidence (False).
        irradiance: irradiance at normal incidence at the centre.

    Returns:
        The ``Rig``.
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
    """The ICT Light Stage X: 346 near-field lights, radius ~1.32 m (bundled table).

    Positions transcribed from dreamworksanimation/moonray (Apache-2.0).

    Args:
        ordering: ``"all"`` (346 lights in table order), ``"polarized"`` (85) or ``"unpolarized"`` (201), the
            stage's own one-light-at-a-time orderings.
        intensity: radiant intensity of every light; None: the value that gives irradiance 1 at the centre from a
            light at the mean radius.

    Returns:
        The ``Rig``.
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


def _check_intensities(inten: np.ndarray, what: str) -> None:
    """Finite (as float32 too), non-negative and not all zero: a rig of dark lights images nothing, and
    every fit or relighting divides by its irradiance."""
    if np.any(inten < 0) or not np.all(np.isfinite(inten)) or np.abs(inten).max(initial=0.0) > _FLOAT32_MAX:
        raise ValueError(f"light intensities must be finite (in float32) and non-negative ({what})")
    if not np.any(inten > 0):
        raise ValueError(f"every light has intensity 0 ({what}); a rig needs at least one lit light")


def _calibration_array(calibration, shape) -> np.ndarray:
    cal = np.asarray(calibration, dtype=np.float64)
    if cal.ndim == 1 and cal.shape[0] == shape[1]:
        cal = np.broadcast_to(cal[None], shape)
    try:
        cal = np.broadcast_to(cal, shape)
    except ValueError:
        raise ValueError(f"calibration must be a scalar, [C={shape[1]}] or [L, C]={shape}, "
                         f"got {np.shape(calibration)}") from None
    if not np.all(np.isfinite(cal)) or np.any(cal < 0):
        raise ValueError("calibration gains must be finite and non-negative")
    return cal


def calibrate(rig: Rig, gains) -> Rig:
    """The rig with each light's intensity multiplied by its RGB calibration gain.

    A light stage measures the gains by imaging a white diffuse target (or a chrome/white sphere pair) under each
    light and dividing by the nominal response; ``calibrate(rig, measured / nominal)`` reproduces the calibrated
    rig. Geometry and solid angles are unchanged.

    Args:
        rig: the nominal rig.
        gains: unitless gains: a scalar, [C] (one colour gain for every light) or [L, C].

    Returns:
        The calibrated ``Rig``.
    """
    g = _calibration_array(gains, tuple(rig.intensity.shape))
    inten = np.asarray(rig.intensity, np.float64) * g
    _check_intensities(inten, "calibrate's argument 'gains' times the rig's intensities")
    inten = jnp.asarray(inten, rig.intensity.dtype)
    return Rig(position=rig.position, intensity=inten,
               solid_angle=rig.solid_angle, near_field=rig.near_field)


def fibonacci_sphere(n: int, radius_mm: float = 1000.0, near_field: bool = False, irradiance: float = 1.0,
                     hemisphere: bool = False) -> Rig:
    """``n`` lights on a Fibonacci (golden-angle) spiral, with the stage's y axis as the pole.

    z_k = 1 - (2k + 1)/n, phi_k = 2 pi k / golden ratio: the directions are
    ``brdf.fibonacci_sphere(n, axis=1, hemisphere)``.

    Args:
        n: the number of lights.
        radius_mm: the sphere's radius (mm), for near-field lights.
        near_field: point sources at ``radius_mm`` giving ``irradiance`` at the centre (True), or distant lights
            delivering ``irradiance`` (False).
        irradiance: irradiance at normal incidence at the centre.
        hemisphere: cover only the upper half (y > 0).

    Returns:
        The ``Rig``.

    References:
        Gonzalez 2010, "Measurement of areas on a sphere using Fibonacci and latitude-longitude lattices",
        Math. Geosci. 42.
    """
    n = int(n)
    if n < 4:
        raise ValueError(f"a Fibonacci sphere rig needs n >= 4 lights, got {n}")
    check_light_count(n, "fibonacci_sphere")
    dirs = brdf_fibonacci_sphere(n, axis=1, hemisphere=hemisphere)
    inten = irradiance * (radius_mm**2 if near_field else 1.0)
    return make_rig(dirs * radius_mm, inten, near_field=near_field)


def directional_rig(directions_path, intensities_path=None) -> Rig:
    """A distant-light rig read from DiLiGenT-style text files.

    ``light_directions.txt`` holds one unit direction "x y z" per line, in the camera frame x right, y up, z toward
    the camera (the stage frame, so no conversion); ``light_intensities.txt`` one RGB intensity "r g b" per line
    (relative irradiance, unitless).

    Args:
        directions_path: the directions file.
        intensities_path: the intensities file (None: every light delivers irradiance 1).

    Returns:
        The ``Rig``.

    Raises:
        ValueError: naming the file, when a row is malformed, the counts disagree, a direction is not unit length
            (tolerance 1e-3) or two lights coincide.

    References:
        Shi et al. 2016, "A benchmark dataset and evaluation for non-Lambertian and uncalibrated photometric
        stereo".
    """
    d = read_light_table(directions_path, "light directions")
    norm = np.linalg.norm(d, axis=1)
    bad = np.nonzero(np.abs(norm - 1) > 1e-3)[0]
    if len(bad):
        raise ValueError(f"{directions_path}: light direction on line {bad[0] + 1} has length "
                         f"{norm[bad[0]]:.4f}, expected 1")
    if intensities_path is None:
        inten = np.ones((len(d), 3))
    else:
        inten = read_light_table(intensities_path, "light intensities")
        if len(inten) != len(d):
            raise ValueError(f"{intensities_path}: {len(inten)} intensity rows for {len(d)} light directions "
                             f"in {directions_path}")
    try:
        return make_rig(d / norm[:, None], inten, near_field=False)
    except ValueError as exc:
        raise ValueError(f"{directions_path}: {exc}") from exc


class Gonioreflectometer(eqx.Module):
    """A gonioreflectometer measurement set (Ward 1992, "Measuring and Modeling
    Anisotropic Reflection", section 2): a planar sample at the origin with its
    normal along +y, a light moving on an arc and a sensor moving on an arc.

    ``rig``: one near-field light per incident angle (in the plane phi_i);
    ``cameras``: one pinhole sensor per (theta_o, phi_o) configuration, looking
    at the sample centre; ``theta_i``, ``theta_o``, ``phi_o`` in radians.
    """

    rig: Rig
    cameras: tuple
    theta_i: Float[Array, " light"]
    theta_o: Float[Array, " view"]
    phi_o: Float[Array, " view"]


def _arc_points(theta, phi, radius):
    # Sample normal +y; phi measured from +x toward +z.
    return radius * np.stack([np.sin(theta) * np.cos(phi), np.cos(theta), np.sin(theta) * np.sin(phi)], axis=-1)


def gonioreflectometer(theta_i_deg, theta_o_deg, phi_o_deg=(0.0,), phi_i_deg: float = 180.0,
                       light_radius_mm: float = 1000.0, sensor_radius_mm: float = 600.0,
                       sensor_resolution: int = 32, sensor_fov_deg: float = 2.0, irradiance: float = 1.0):
    """Ward's gonioreflectometer as a rig plus cameras (see ``Gonioreflectometer``).

    Each light is a point source giving ``irradiance`` at normal incidence at the sample centre. The lights all
    lie on one great circle, so their solid angles are lunes (2 x angular spacing), which still sum to 4 pi.

    Args:
        theta_i_deg: the lights' polar angles (degrees), on the arc of azimuth ``phi_i_deg``.
        theta_o_deg, phi_o_deg: the sensors' polar angles and azimuths (degrees): a sensor at every
            (theta_o, phi_o) (the sensor arc rotates about the normal to reach each phi_o).
        phi_i_deg: the lights' azimuth (degrees).
        light_radius_mm: the lights' distance from the sample (mm).
        sensor_radius_mm: the sensors' distance from the sample (mm).
        sensor_resolution: each sensor's image width and height (pixels).
        sensor_fov_deg: each sensor's field of view (degrees).
        irradiance: irradiance at normal incidence at the sample centre.

    Returns:
        The ``Gonioreflectometer`` (rig and cameras).

    References:
        Ward 1992, "Measuring and modeling anisotropic reflection", sec. 2.
    """
    from ._camera import look_at

    ti = np.deg2rad(np.atleast_1d(np.asarray(theta_i_deg, np.float64)))
    to = np.deg2rad(np.atleast_1d(np.asarray(theta_o_deg, np.float64)))
    po = np.deg2rad(np.atleast_1d(np.asarray(phi_o_deg, np.float64)))
    for name, a in (("theta_i_deg", ti), ("theta_o_deg", to)):
        if a.size == 0 or np.any(a < 0) or np.any(a >= np.pi / 2):
            raise ValueError(f"gonioreflectometer: {name} must be non-empty and in [0, 90) degrees")
    lights = _arc_points(ti, np.deg2rad(phi_i_deg), light_radius_mm)
    if len(lights) < 3:
        raise ValueError("gonioreflectometer: give at least 3 incident angles (the rig's solid angles need them)")
    rig = make_rig(lights, irradiance * light_radius_mm**2, near_field=True)
    T, Pp = np.meshgrid(to, po, indexing="ij")
    eyes = _arc_points(T.ravel(), Pp.ravel(), sensor_radius_mm)
    cams = []
    for e, t in zip(eyes, T.ravel(), strict=True):
        # At normal view, 'up' along +y is parallel to the view direction: use -z then.
        up = (0.0, 1.0, 0.0) if t > 1e-6 else (0.0, 0.0, -1.0)
        cams.append(look_at(e, (0.0, 0.0, 0.0), up=up, fov_deg=sensor_fov_deg,
                            width=sensor_resolution, height=sensor_resolution))
    return Gonioreflectometer(rig=rig, cameras=tuple(cams), theta_i=jnp.asarray(ti, jnp.float32),
                              theta_o=jnp.asarray(T.ravel(), jnp.float32), phi_o=jnp.asarray(Pp.ravel(), jnp.float32))


def light_stage_x_faces(source: str = "table") -> np.ndarray:
    """Triangulation of the 85 polarized Light Stage X lights, wound counter-clockwise seen from outside.

    ``source="table"``: the bundled table's faces (1-based in the file), with its repeated faces removed (the file
    repeats two triangles 5 and 6 times: 177 rows, 168 distinct). The table's fan around polarized light 78 (raw
    row 322) was built with that light at the duplicated position of row 197; with the restored position, the
    triangulation of the actual directions is ``source="hull"`` (their convex hull, 166 faces), which shares 156
    faces with the table.

    Args:
        source: ``"table"`` or ``"hull"``.

    Returns:
        0-based indices [F, 3] into ``light_stage_x("polarized")``.
    """
    pos = np.asarray(light_stage_x("polarized").position, np.float64)
    if source == "table":
        f = np.asarray(_lsx_table()["faces"], np.int64) - 1
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(first)]
    elif source == "hull":
        from scipy.spatial import ConvexHull

        f = ConvexHull(pos / np.linalg.norm(pos, axis=1, keepdims=True)).simplices.astype(np.int64)
    else:
        raise ValueError(f"source must be 'table' or 'hull', got {source!r}")
    v = pos[f]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    inward = np.sum(n * v.mean(axis=1), axis=1) < 0
    f[inward] = f[inward][:, ::-1]
    return f
