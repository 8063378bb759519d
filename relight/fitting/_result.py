"""The result of a fit: the ``Fit`` Module, its result codes (``RESULTS``) and the rig's roughness floor.

``RESULTS`` extends Optimistix's enumeration (as ``optimistix.RESULTS`` extends Lineax's) with the
codes the fitter adds to a solve's own; ``Fit.result`` stores, per sample, the index of a ``RESULTS``
item as an int32 array (an enumeration item is one scalar, a fit has one code per sample). The ints
are made from the items in one place, :func:`result_code`, through public pytree API only.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float, Int

import stage

from ..materials._maps import BLINN_PHONG, SUBSURFACE, LadderBRDF, MaterialMaps, material_maps

# The fitter's roughness prior, separate from the model's own floor
# (brdf.ALPHA_MIN): below this no light stage resolves a GGX lobe.
ALPHA_FIT_MIN = 0.02
# Every parameter a rung may report an uncertainty for (0 where not fitted, inf where unknown).
PARAM_NAMES = ("rho_d.r", "rho_d.g", "rho_d.b", "rho_s", "alpha_x", "alpha_y", "phi", "normal.x", "normal.y")
# Fewer valid observations (lights x views) than this leave a sample underdetermined.
MIN_OBSERVATIONS = 8


class RESULTS(optx.RESULTS):  # pyright: ignore
    """Optimistix's result codes (``optimistix.RESULTS``: ``successful``,
    ``nonlinear_max_steps_reached``, ...) and the fitter's own: ``rejected``,
    a solve whose value was not finite or raised the cost above its start's
    (the sample keeps its start)."""

    rejected = ("The solve gave a non-finite value or a higher cost than its start; "
                "the sample keeps its start.")


def result_code(item) -> Int[Array, " *batch"]:
    """The int index [*batch] of a ``RESULTS`` item (scalar, or batched by ``jax.vmap``).

    Args:
        item: an item of ``RESULTS`` (promote an ``optimistix.RESULTS`` item with
            ``RESULTS.promote`` first).

    Returns:
        Its index as an int32 array: what ``Fit.result`` stores per sample.
    """
    if not isinstance(item, RESULTS):
        raise TypeError(f"result_code: expects an item of relight.fitting.RESULTS, got {item!r}")
    (value,) = jax.tree_util.tree_leaves(item)  # an enumeration item is a pytree of its one index array
    return jnp.asarray(value, jnp.int32)


def result_message(code: int) -> str:
    """The message of the ``RESULTS`` item stored as ``code`` in ``Fit.result`` ("" for successful).

    Args:
        code: one entry of ``Fit.result``.

    Returns:
        The item's message (``RESULTS[item]``).
    """
    item = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(RESULTS.successful),
                                        [np.asarray(int(code), np.int32)])
    return RESULTS[item]


# The codes the driver compares against, as ints, made once.
SUCCESSFUL = int(result_code(RESULTS.successful))
MAX_STEPS = int(result_code(RESULTS.nonlinear_max_steps_reached))
REJECTED = int(result_code(RESULTS.rejected))


def rig_alpha_floor(rig: stage.Rig) -> float:
    """The smallest GGX roughness a rig's angular light spacing resolves.

    A GGX lobe's half width at half maximum is about 0.64 alpha in the half
    vector, so about 1.3 alpha in light direction, and its full width about 2.6
    alpha; with lights a median nearest-neighbour angle Delta apart, at least
    two lights fall across the lobe only for alpha >= Delta / 2.6 (Light Stage X:
    Delta ~ 0.19 rad, floor ~ 0.07).

    Args:
        rig: the light rig (its ``directions``).

    Returns:
        The floor, never below ``ALPHA_FIT_MIN``.
    """
    d = np.asarray(rig.directions, np.float64)
    if len(d) < 2:
        return ALPHA_FIT_MIN
    cos = np.clip(d @ d.T, -1.0, 1.0)
    np.fill_diagonal(cos, -1.0)
    spacing = float(np.median(np.arccos(cos.max(axis=1))))
    return float(max(ALPHA_FIT_MIN, spacing / 2.6))


class Fit(eqx.Module):
    """The result of :func:`relight.fit`, per sample.

    **Attributes:**

    - ``rho_d`` [P, 3], ``rho_s`` [P, 1], ``alpha`` [P, 2] (along the fitted
      tangent / bitangent), ``normal`` and ``tangent`` [P, 3] (world space):
      the parameter maps.
    - ``model`` [P]: the ladder rung, an index into ``relight.MODELS``
      (SUBSURFACE where ``mfp_rung`` > 0).
    - ``residual`` [P]: the RMS residual over all valid observations (the
      capture's radiance units); ``heldout`` [P]: the held-out RMS
      (``model="auto"``, else 0; the capture's units).
    - ``result`` [P] int32: the index of each sample's ``RESULTS`` item
      (:func:`result_code`; ``SUCCESSFUL`` = 0, ``RESULTS.rejected``: the
      solve was rejected and the sample kept its start; message:
      :func:`result_message`); ``steps`` [P]: solver steps taken;
      ``observed`` [P]: valid observations.
    - ``uncertainty`` [P, 9]: one-sigma uncertainties from J^T J (names in
      ``PARAM_NAMES``, in the parameters' units; 0 where a rung has no such
      parameter, inf where the data leave a fitted parameter unknown: no or
      too few observations, a direction nothing constrains; ``unidentified``
      flags those).
    - ``alpha_floor`` (static): the roughness floor the rig resolves (a fitted
      alpha at the floor means "narrower than the rig can tell", flagged by
      ``unresolved``).
    - ``mfp`` [P, 3]: the mean free path (mm; after
      :func:`relight.fit_subsurface`, else None).
    - ``solver`` (static): the string given to :func:`relight.fit`, or the
      class and tolerances of the Optimistix solver object.
    - ``mfp_sigma`` [P, 3] (after :func:`relight.fit_subsurface`, else None):
      the 1-sigma of ln(mfp) per channel from the data alone (s^2 (J^T J)^-1
      with the albedo marginalised, the prior left out; for a per-region texel
      the region's shared value's, the texels' informations summed; inf where
      not identifiable or no subsurface).
    - ``mfp_rung`` [P] int32 (else None): 0 = no subsurface (the BRDF's local
      Lambert term, mfp 0); 1 = the region's mean free path; 2 = the texel's own.
    - ``min_observed`` (static): the fewest valid observations a sample needs
      (``failed`` below it): ``MIN_OBSERVATIONS`` = 8 (lights x views) for
      :func:`relight.fit`, ``MIN_PATTERN_OBSERVATIONS`` = 4 pattern
      measurements for :func:`relight.fitting.fit_patterns`.
    """

    rho_d: Float[Array, "sample 3"]
    rho_s: Float[Array, "sample 1"]
    alpha: Float[Array, "sample 2"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    model: Int[Array, " sample"]
    residual: Float[Array, " sample"]
    heldout: Float[Array, " sample"]
    result: Int[Array, " sample"]
    steps: Int[Array, " sample"]
    observed: Float[Array, " sample"]
    uncertainty: Float[Array, "sample 9"]
    alpha_floor: float = eqx.field(static=True, default=ALPHA_FIT_MIN)
    mfp: Float[Array, "sample 3"] | None = None
    solver: str = eqx.field(static=True, default="lm")
    mfp_sigma: Float[Array, "sample 3"] | None = None
    mfp_rung: Int[Array, " sample"] | None = None
    min_observed: int = eqx.field(static=True, default=MIN_OBSERVATIONS)
    # ambiguous's bar on the albedo's relative 1-sigma.
    AMBIGUOUS_RELATIVE_SIGMA: ClassVar[float] = 0.1
    # mfp_identified's bar on the 1-sigma of ln mfp: 25% relative.
    IDENTIFIED_SIGMA: ClassVar[float] = 0.25
    # collapsed's bars. F0 below 1% is a refractive index under 1.22, below any real dielectric's (water 2%,
    # skin 2.8%): the fit switched the lobe off. A roughness within 5% of its top (1) spreads the lobe over the
    # hemisphere, where it trades places with the diffuse term.
    COLLAPSED_F0: ClassVar[float] = 0.01
    COLLAPSED_ALPHA: ClassVar[float] = 0.95

    @property
    def f0(self):
        """The specular albedo as Schlick's F0 [P, 1] (same as ``rho_s``)."""
        return self.rho_s

    @property
    def failed(self):
        """Samples whose solve failed (``result`` not ``SUCCESSFUL``) or that had too few observations."""
        return (self.result != SUCCESSFUL) | (self.observed < self.min_observed)

    @property
    def mfp_identified(self):
        """[P, 3] bool: texel-channels whose mean free path the data pin to a 1-sigma of ln mfp below
        IDENTIFIED_SIGMA (0.25); None before :func:`relight.fit_subsurface`."""
        if self.mfp_sigma is None:
            return None
        return jnp.isfinite(self.mfp_sigma) & (self.mfp_sigma < self.IDENTIFIED_SIGMA)

    @property
    def ambiguous(self):
        """[P] bool: samples whose albedo the data leave loose, a 1-sigma above
        ``AMBIGUOUS_RELATIVE_SIGMA`` (10%) of rho_d in some channel (or
        unknown). Noise then lets a broad grey lobe trade places with the
        diffuse term at an equal or lower cost than the truth (docs/fit.md)."""
        rel = self.uncertainty[:, :3] / jnp.maximum(self.rho_d, 1e-6)
        return jnp.any(~(rel <= self.AMBIGUOUS_RELATIVE_SIGMA), axis=1) & (self.observed >= self.min_observed)

    @property
    def collapsed(self):
        """[P] bool: samples of a lobed BRDF rung (Blinn-Phong, GGX, anisotropic GGX) whose lobe collapsed to
        a bound: F0 below ``COLLAPSED_F0`` (1%) or a roughness at or above ``COLLAPSED_ALPHA`` (0.95).

        A lobe collapses where the lights do not constrain it (no light near the texel's mirror
        direction, or Lambertian data under a fixed lobed rung). Its parameters then sit where the fit's
        sigmoid bounds flatten the Jacobian and are not measurements. A lobe switched off (F0 below the
        bound) is held there for the uncertainties: its sigmas are inf (``unidentified``), the albedo's and
        the normal's those of the free parameters. Samples with too few observations are ``failed``, not
        collapsed."""
        at_bound = (self.rho_s[:, 0] < self.COLLAPSED_F0) | (jnp.max(self.alpha, axis=1) >= self.COLLAPSED_ALPHA)
        return self._lobed & at_bound & (self.observed >= self.min_observed)

    @property
    def lobe_unmeasured(self):
        """[P] bool: samples of a lobed BRDF rung, not ``collapsed``, whose F0 and roughness the sample's own
        data leave unknown (sigma inf): a lobe taken from the neighbours where no light sampled the sample's
        own (``relight.fit(..., neighbour_lobes=True)``, :mod:`relight.fitting._neighbours`), or, rarely, a
        fitted lobe nothing constrains. Its values are a prior, not a measurement."""
        unknown = ~jnp.isfinite(self.uncertainty[:, 3]) & ~jnp.isfinite(self.uncertainty[:, 4])
        return self._lobed & unknown & ~self.collapsed & (self.observed >= self.min_observed)

    @property
    def _lobed(self):
        """[P] bool: samples of a lobed BRDF rung (Blinn-Phong, GGX, anisotropic GGX)."""
        return (self.model >= BLINN_PHONG) & (self.model < SUBSURFACE)

    @property
    def unidentified(self):
        """[P, 9] bool (``PARAM_NAMES``): fitted parameters the data leave unknown (uncertainty inf)."""
        return ~jnp.isfinite(self.uncertainty)

    @property
    def unresolved(self):
        """Samples whose lobe is at the rig's roughness floor (sharper than it resolves)."""
        return (self.model >= BLINN_PHONG) & (self.alpha[:, 0] < 1.25 * self.alpha_floor)

    def maps(self, surface: stage.Surface) -> MaterialMaps:
        """The fit as material maps over ``surface`` (the fitted frame and rungs)."""
        return material_maps(surface, self.rho_d, self.rho_s, self.alpha, normal=self.normal, tangent=self.tangent,
                             mfp=self.mfp, model=self.model)

    def material(self) -> LadderBRDF:
        """The fitted BRDF (leading sample axis), in the fitted frame."""
        return LadderBRDF(self.rho_d, self.rho_s, self.alpha, self.model[:, None], include_diffuse=True)


# The Fit's per-sample fields fit assembles (and on_block receives), with their trailing shape and kind.
FIELDS = dict(rho_d=((3,), "f"), rho_s=((1,), "f"), alpha=((2,), "f"), normal=((3,), "f"), tangent=((3,), "f"),
              model=((), "i"), residual=((), "f"), heldout=((), "f"), result=((), "i"), steps=((), "i"),
              observed=((), "o"), uncertainty=((9,), "f"))


def fit_from_arrays(out: dict, dt, floor: float, solver_name: str, min_observed: int = MIN_OBSERVATIONS) -> Fit:
    """A ``Fit`` from its per-sample NumPy arrays (the ``on_block`` fields, [P, ...])."""
    f = lambda x: jnp.asarray(x, dt)  # noqa: E731
    i32 = lambda x: jnp.asarray(x, jnp.int32)  # noqa: E731
    return Fit(rho_d=f(out["rho_d"]), rho_s=f(out["rho_s"]), alpha=f(out["alpha"]), normal=f(out["normal"]),
               tangent=f(out["tangent"]), model=i32(out["model"]), residual=f(out["residual"]),
               heldout=f(out["heldout"]), result=i32(out["result"]), steps=i32(out["steps"]),
               observed=jnp.asarray(out["observed"], jnp.float32), uncertainty=f(out["uncertainty"]),
               alpha_floor=floor, solver=solver_name, min_observed=int(min_observed))
