"""The surface diffusion operator: spread irradiance between nearby surface
samples with a radial profile (Jensen & Buhler 2002's hierarchical integration
done exactly over a fixed neighbourhood).

Contract (used by ``stage`` to simulate and by ``relight`` to fit):

    ops = DiffusionOperator.build(positions [P, 3] mm, areas [P] mm^2, radius_mm)
    exitance [P, C] = ops.apply(profile, irradiance [P, C])          # radiant exitance M_o
    tail [..., C]   = ops.tail(profile)                               # energy beyond radius_mm

(``build(..., receivers=idx)`` restricts the output to R chosen samples: [R, C].)

``build`` is NumPy/SciPy, runs once per geometry and is not differentiated: a
KD-tree finds, for every sample, all other samples within ``radius_mm`` in 3-D
(Euclidean) distance, so samples on both sides of a UV seam are neighbours.
``apply`` is pure JAX: it works under ``jit``/``vmap``/``grad`` and is
differentiable with respect to the profile's parameters and the irradiance.

Weights. M_i = w_ii E_i + sum_j R_i(|x_i - x_j|) A_j E_j over neighbours j != i,
where R_i is the receiving sample's profile and w_ii = ``cumulative(rho_i)`` is
the exact energy of the profile over the sample's own disc of equal area,
rho_i = sqrt(A_i / pi) (the profile may be singular at r = 0 -- Burley's is 1/r --
so it is integrated, not sampled, there). With equal areas and one profile the
weights are symmetric, w_ij = w_ji. Uniform irradiance E gives
M_i ~ cumulative(radius) E = (total - tail) E, up to the quadrature error of
the sum, which shrinks with the sample spacing. ``normalize=True`` rescales each
row to sum to exactly total - tail (energy conserving on any geometry,
including open boundaries and curved surfaces, at the price of exact symmetry).

Memory: neighbour lists are stored padded to the largest neighbour count K as
int32 indices and float distances, P x K each; ``apply`` processes ``chunk``
rows at a time under ``jax.lax.map`` with rematerialisation, so the peak
working set is chunk x K x C, forward and backward.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int
from scipy.spatial import cKDTree

from brdf import widest_float

from ._common import AbstractProfile, cast_floats

# Rows per chunk are chosen so that one chunk's gathered neighbours
# (chunk x K x C floats, C = 3) stay near this many elements (~50 MB in float64).
_CHUNK_ELEMENTS = 1 << 21
# Pairs per KD-tree block in build: bounds the (int64, int64, float64) pair list
# scipy returns for a block of rows (~100 MB).
_BUILD_PAIRS = 1 << 22


class DiffusionOperator(eqx.Module):
    """Sparse surface diffusion operator over P samples (see the module docstring).

    Fields: ``receivers`` [R] the samples whose exitance is computed (all P by
    default), ``index`` [R, K] their neighbours' indices into the P samples (int32;
    padding points at the receiver itself), ``distance`` [R, K] 3-D distances in mm,
    ``valid`` [R, K], ``area`` [P] in mm^2, ``self_radius`` [R] = sqrt(area/pi) in mm;
    static ``radius`` (mm) and ``chunk`` (rows per step).
    """

    index: Int[Array, "receiver neighbour"]
    distance: Float[Array, "receiver neighbour"]
    valid: Bool[Array, "receiver neighbour"]
    area: Float[Array, " sample"]
    self_radius: Float[Array, " receiver"]
    receivers: Int[Array, " receiver"]
    radius: float = eqx.field(static=True)
    chunk: int = eqx.field(static=True)

    @classmethod
    def build(
        cls,
        positions: Float[ArrayLike, "sample 3"],
        areas: Float[ArrayLike, " sample"],
        radius_mm: float,
        *,
        max_neighbours: int | None = None,
        chunk: int | None = None,
        dtype=None,
        workers: int = 1,
        receivers: Int[ArrayLike, " receiver"] | None = None,
    ) -> DiffusionOperator:
        """Neighbour lists of every sample within ``radius_mm`` (3-D distance) by KD-tree.

        ``positions`` [P, 3] in mm, ``areas`` [P] in mm^2 (> 0). ``max_neighbours``
        keeps only the nearest ones (their loss shows in ``captured``); ``chunk``
        overrides the rows per step of ``apply``; ``dtype`` of the distances and
        areas (default: float32, or float64 when x64 is on); ``workers`` for scipy;
        ``receivers`` [R] restricts the output to those samples (e.g. to evaluate a
        fine reference at a subset), all samples still acting as sources.
        Choose ``radius_mm`` with ``energy_radius(profile, 0.99)`` or similar: the
        energy beyond it is reported by ``tail``.
        """
        pos = np.asarray(positions, np.float64)
        area = np.asarray(areas, np.float64)
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ValueError(f"DiffusionOperator.build: positions must have shape [P, 3], got {pos.shape}")
        P = pos.shape[0]
        if P == 0:
            raise ValueError("DiffusionOperator.build: positions is empty (P = 0)")
        if area.shape != (P,):
            raise ValueError(f"DiffusionOperator.build: areas must have shape [P={P}], got {area.shape}")
        if not np.all(np.isfinite(pos)):
            raise ValueError("DiffusionOperator.build: positions (mm) must be finite")
        if not np.all(np.isfinite(area)) or np.any(area <= 0):
            raise ValueError(f"DiffusionOperator.build: areas (mm^2) must be finite and > 0, got min {area.min()!r}")
        if not (isinstance(radius_mm, (int, float, np.floating)) and math.isfinite(radius_mm) and radius_mm > 0):
            raise ValueError(f"DiffusionOperator.build: radius_mm must be a finite float > 0, got {radius_mm!r}")
        if max_neighbours is not None and (not isinstance(max_neighbours, int) or max_neighbours < 1):
            raise ValueError(f"DiffusionOperator.build: max_neighbours must be an int >= 1, got {max_neighbours!r}")
        radius = float(radius_mm)
        if receivers is None:
            recv = np.arange(P)
        else:
            recv = np.asarray(receivers)
            if recv.ndim != 1 or not np.issubdtype(recv.dtype, np.integer) or np.any(recv < 0) or np.any(recv >= P):
                raise ValueError(f"DiffusionOperator.build: receivers must be integer indices into the P={P} samples")
        R = recv.shape[0]
        tree = cKDTree(pos)
        counts = tree.query_ball_point(pos[recv], r=radius, return_length=True, workers=workers) - 1  # minus self
        K = max(int(counts.max()), 1) if R else 1
        if max_neighbours is not None:
            K = min(K, max_neighbours)
        index = np.repeat(recv.astype(np.int32)[:, None], K, axis=1)
        dist = np.zeros((R, K), np.float64)
        valid = np.zeros((R, K), bool)
        # rows per block so that one block's pair list stays near _BUILD_PAIRS pairs
        block = max(1, _BUILD_PAIRS // (K + 1))
        for s in range(0, R, block):
            e = min(s + block, R)
            pairs = cKDTree(pos[recv[s:e]]).sparse_distance_matrix(tree, radius, output_type="ndarray")
            i, j, d = pairs["i"] + s, pairs["j"], pairs["v"]  # i: receiver row, j: sample
            keep = recv[i] != j  # the sample itself is handled by the self weight
            i, j, d = i[keep], j[keep], d[keep]
            order = np.lexsort((d, i))  # by row, nearest first
            i, j, d = i[order], j[order], d[order]
            start = np.searchsorted(i, np.arange(s, e))
            slot = np.arange(i.size) - start[i - s]
            keep = slot < K
            i, j, d, slot = i[keep], j[keep], d[keep], slot[keep]
            index[i, slot] = j
            dist[i, slot] = d
            valid[i, slot] = True
        if dtype is None:
            dtype = jnp.result_type(float)
        if chunk is None:
            chunk = max(16, min(max(R, 1), _CHUNK_ELEMENTS // max(K, 1) // 3))
        if not isinstance(chunk, int) or chunk < 1:
            raise ValueError(f"DiffusionOperator.build: chunk must be an int >= 1, got {chunk!r}")
        return cls(
            index=jnp.asarray(index),
            distance=jnp.asarray(dist, dtype),
            valid=jnp.asarray(valid),
            area=jnp.asarray(area, dtype),
            self_radius=jnp.asarray(np.sqrt(area[recv] / np.pi), dtype),
            receivers=jnp.asarray(recv, jnp.int32),
            radius=radius,
            chunk=int(chunk),
        )

    @property
    def num_samples(self) -> int:
        """P, the number of samples (sources)."""
        return self.area.shape[0]

    @property
    def num_receivers(self) -> int:
        """R, the number of samples whose exitance ``apply`` returns (P unless ``receivers`` was given)."""
        return self.index.shape[0]

    def apply(
        self,
        profile: AbstractProfile,
        irradiance: Float[ArrayLike, "sample channel"],
        *,
        normalize: bool = False,
    ) -> Float[Array, "receiver channel"]:
        """Radiant exitance M_i = sum_j w_ij E_j (see the module docstring), [R, C]
        (R = P unless the operator was built for a subset of ``receivers``).

        ``profile`` has parameters of shape [C] (one material) or [R, C] (one per
        receiving sample); ``irradiance`` [P, C] in W/mm^2 (any consistent unit).
        ``normalize=True`` makes every row sum to ``profile.cumulative(radius)``.
        """
        E = jnp.asarray(irradiance)
        P = self.num_samples
        if E.ndim != 2 or E.shape[0] != P:
            raise ValueError(f"DiffusionOperator.apply: irradiance must have shape [P={P}, C], got {E.shape}")
        return self._map(profile, E, normalize=normalize)

    def captured(self, profile: AbstractProfile) -> Float[Array, "receiver channel"]:
        """Row sums sum_j w_ij [R, C]: the exitance under unit irradiance (before normalisation)."""
        C = profile.total().shape[-1]
        return self._map(profile, jnp.ones((self.num_samples, C), self.distance.dtype), normalize=False)

    def tail(self, profile: AbstractProfile) -> Float[Array, "*pbatch channel"]:
        """Energy of the profile beyond ``radius`` (what the truncated neighbourhood drops)."""
        r = jnp.full(profile.batch_shape, self.radius, self.distance.dtype)
        return profile.tail(r)

    def row_weights(
        self, profile: AbstractProfile
    ) -> tuple[Float[Array, "sample neighbour channel"], Float[Array, "sample channel"]]:
        """(neighbour weights w_ij [P, K, C] aligned with ``index``, self weights w_ii [P, C]),
        unchunked: for small P (tests, inspection) or to precompute a fixed profile."""
        self._per_row(profile)
        op, profile, _ = self._common_dtype(profile)
        per_sample = profile.batch_shape != ()
        area = op.area[op.index]
        return _weights(profile, op.distance, op.valid, area, op.self_radius, per_sample=per_sample)

    # --- internals ----------------------------------------------------------------
    def _per_row(self, profile):
        bs = profile.batch_shape
        if bs not in ((), (self.num_receivers,)):
            raise ValueError(
                f"DiffusionOperator: profile parameters must have batch shape () or (R={self.num_receivers},), got {bs}"
            )
        return profile

    def _common_dtype(self, profile, *arrays):
        """The operator, the profile and ``arrays`` in one floating dtype, the widest of them, cast
        explicitly: a float32 operator applied with a float64 profile (or the reverse) is not an
        implicit promotion, which ``jax_numpy_dtype_promotion="strict"`` refuses."""
        params = jax.tree_util.tree_leaves(eqx.filter(profile, eqx.is_inexact_array))
        dt = widest_float(self.distance, *params, *arrays)
        fields = (self.distance, self.area, self.self_radius)
        op = eqx.tree_at(lambda o: (o.distance, o.area, o.self_radius), self, cast_floats(fields, dt))
        return op, cast_floats(profile, dt), tuple(cast_floats(jnp.asarray(a), dt) for a in arrays)

    def _map(self, profile, E, *, normalize):
        self._per_row(profile)
        op, profile, (E,) = self._common_dtype(profile, E)
        return op._map_common(profile, E, normalize=normalize)

    def _map_common(self, profile, E, *, normalize):
        per_sample = profile.batch_shape != ()
        P, K = self.index.shape  # receivers x neighbours
        if P == 0:
            return jnp.zeros((0, E.shape[1]), E.dtype)
        n = min(self.chunk, P)
        n_chunks = -(-P // n)
        pad = n_chunks * n - P

        def rows(x, fill):
            x = jnp.concatenate([x, jnp.full((pad,) + x.shape[1:], fill, x.dtype)]) if pad else x
            return x.reshape((n_chunks, n) + x.shape[1:])

        # per-sample profiles: the leaves with a leading sample axis are cut into
        # chunks (padding repeats row 0, so padded rows hold valid parameters)
        def batched(x):
            return eqx.is_array(x) and x.ndim >= 2 and x.shape[0] == P

        dyn, static = eqx.partition(profile, batched if per_sample else (lambda x: False))

        def rows_edge(x):
            x = jnp.concatenate([x, jnp.repeat(x[:1], pad, axis=0)]) if pad else x
            return x.reshape((n_chunks, n) + x.shape[1:])

        dyn_rows = jax.tree_util.tree_map(rows_edge, dyn)
        xs = (
            rows(self.index, 0),
            rows(self.distance, 0.0),
            rows(self.valid, False),
            rows(self.self_radius, 0.0),
            rows(E[self.receivers], 0.0),
            dyn_rows,
        )
        area = self.area
        radius = self.radius

        @jax.checkpoint
        def body(x):
            idx, dist, valid, rho, E_self, dyn_c = x
            prof = eqx.combine(dyn_c, static)
            w, w_self = _weights(prof, dist, valid, area[idx], rho, per_sample=per_sample)
            M = w_self * E_self + jnp.einsum("nkc,nkc->nc", w, E[idx])
            if normalize:
                if per_sample:
                    target = prof.cumulative(jnp.full(rho.shape, radius, dist.dtype))
                else:
                    target = prof.cumulative(jnp.asarray(radius, dist.dtype))[None]
                row = w_self + jnp.sum(w, axis=1)
                # rows of padding (rho = 0, no neighbours) have row sum 0: leave them at 0
                M = M * jnp.where(row > 0, target / jnp.where(row > 0, row, 1), 0)
            return M

        out = jax.lax.map(body, xs)
        return out.reshape((n_chunks * n,) + out.shape[2:])[:P]


def _weights(profile, dist, valid, area_nb, rho, *, per_sample):
    """Neighbour weights [n, K, C] and self weights [n, C] for a block of rows."""
    if per_sample:
        # radial broadcasts r[..., None] against parameters [n, C]: evaluate at
        # dist.T [K, n] -> [K, n, C], i.e. row i's own profile at its distances
        R = jnp.swapaxes(profile.radial(dist.T), 0, 1)
    else:
        R = profile.radial(dist)
    w_self = profile.cumulative(rho)  # [n, C]
    w = jnp.where(valid[..., None], R * area_nb[..., None], 0.0)
    return w, w_self
