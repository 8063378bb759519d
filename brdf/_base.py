"""The common interface of every reflectance model, the description of its
fittable parameters, and the small helpers that validate and prepare inputs.

Conventions (DESIGN.md): directions are unit vectors in the local shading frame
(z = normal, ``cos_theta = w[..., 2]``); a model returns f_r in 1/sr, with no
cosine factor, 0 where either direction is at or below the horizon. Models with
1/cos factors or a half vector evaluate a direction whose cosine is below
``brdf.grazing_floor(dtype)`` (8 ulps of 1) at the floor (``brdf.lift_grazing``),
so values and gradients stay finite at grazing (every public model is held to
that).
"""

from __future__ import annotations

import abc
from typing import ClassVar, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._safe import safe_log

Transform = Literal["softplus", "sigmoid", "exp", "identity"]
_TRANSFORMS = ("softplus", "sigmoid", "exp", "identity")


class ParamSpec(eqx.Module):
    """Bounds of one fittable parameter and the smooth bijection the fitter uses
    between its unconstrained value u (any real) and the physical value x.

    - ``"sigmoid"``: x = lower + (upper - lower) * sigmoid(u)  (both bounds finite)
    - ``"softplus"``: x = lower + softplus(u)                  (upper = inf)
    - ``"exp"``: x = lower + exp(u)                             (upper = inf)
    - ``"identity"``: x = u                                     (bounds only documented)
    """

    lower: float = eqx.field(static=True)
    upper: float = eqx.field(static=True)
    transform: str = eqx.field(static=True)

    def __check_init__(self):
        if self.transform not in _TRANSFORMS:
            raise ValueError(f"ParamSpec.transform must be one of {_TRANSFORMS}, got {self.transform!r}")
        if not self.lower < self.upper:
            raise ValueError(f"ParamSpec needs lower < upper, got lower={self.lower}, upper={self.upper}")
        if self.transform == "sigmoid" and not (np.isfinite(self.lower) and np.isfinite(self.upper)):
            raise ValueError("ParamSpec with transform 'sigmoid' needs finite lower and upper bounds")
        if self.transform in ("softplus", "exp") and not np.isfinite(self.lower):
            raise ValueError(f"ParamSpec with transform {self.transform!r} needs a finite lower bound")


def from_unconstrained(spec: ParamSpec, u: ArrayLike) -> Array:
    """The physical value x of a parameter from its unconstrained value u (see ``ParamSpec``).

    Args:
        spec: the parameter's bounds and transform.
        u: the unconstrained value.

    Returns:
        x, the shape of ``u``.
    """
    u = jnp.asarray(u)
    if spec.transform == "identity":
        return u
    if spec.transform == "sigmoid":
        return spec.lower + (spec.upper - spec.lower) * jax.nn.sigmoid(u)
    if spec.transform == "softplus":
        return spec.lower + jax.nn.softplus(u)
    return spec.lower + jnp.exp(u)  # "exp"


def to_unconstrained(spec: ParamSpec, x: ArrayLike) -> Array:
    """The unconstrained value u of a physical value x: the inverse of ``from_unconstrained``.

    Values on or outside an open bound are first moved just inside it (by a relative step of about 1e-6 of the
    range, or the dtype's resolution), so the result is always finite.

    Args:
        spec: the parameter's bounds and transform.
        x: the physical value.

    Returns:
        u, the shape of ``x``.
    """
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    if spec.transform == "identity":
        return x
    eps = float(jnp.finfo(x.dtype).eps)
    if spec.transform == "sigmoid":
        width = spec.upper - spec.lower
        # Keep t inside (0, 1) so that the logit stays finite.
        t = jnp.clip((x - spec.lower) / width, 4 * eps, 1 - 4 * eps)
        return safe_log(t) - safe_log(1 - t)
    y = jnp.maximum(x - spec.lower, jnp.asarray(max(1e-6, 4 * eps) * max(1.0, abs(spec.lower)), x.dtype))
    if spec.transform == "softplus":
        # inverse softplus, log(exp(y) - 1), written to avoid overflow for large y
        return y + safe_log(-jnp.expm1(-y))
    return jnp.log(y)  # "exp"


class AbstractBRDF(eqx.Module):
    """A reflectance model f_r(wi, wo) in the local shading frame.

    Subclasses are final equinox Modules whose array fields are the physical
    parameters, each of shape ``[*batch, C]``, ``[*batch, 1]`` (the same rank as
    the directions, since rank promotion raises) or 0-d.

    ``per_sample`` (class attribute): False for models whose arrays are one
    table or network shared by every sample (MERL, NBRDF), so a sample chunk
    never slices them even when an axis happens to match the sample count.
    """

    per_sample: ClassVar[bool] = True

    @abc.abstractmethod
    def __call__(
        self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]
    ) -> Float[Array, "*batch C"]:
        """f_r(wi, wo) in 1/sr, no cosine factor; 0 when wi or wo is at or below
        the horizon (cos_theta <= 0)."""

    @abc.abstractmethod
    def fittable(self) -> dict[str, ParamSpec]:
        """Fittable parameters: dotted attribute path -> ParamSpec.

        The names are paths into this Module (``"albedo"``,
        ``"distribution.alpha_x"``, ``"terms.1.fresnel.f0"``), so that
        :func:`get_params` and :func:`set_params` read and replace them.
        """


# ---------------------------------------------------------------------------
# Parameter paths


def _resolve(obj, part: str):
    if part.isdigit():
        return obj[int(part)]
    return getattr(obj, part)


def get_params(model: eqx.Module, names=None) -> dict[str, Array]:
    """Current values of a model's fittable parameters.

    Args:
        model: a brdf model.
        names: the parameter names (as in ``model.fittable()``); None: all of them.

    Returns:
        ``name -> array``.
    """
    names = list(model.fittable()) if names is None else list(names)
    out = {}
    for name in names:
        obj = model
        try:
            for part in name.split("."):
                obj = _resolve(obj, part)
        except (AttributeError, IndexError) as e:
            raise ValueError(f"{type(model).__name__} has no parameter {name!r}") from e
        out[name] = obj
    return out


def set_params(model: eqx.Module, values: dict[str, ArrayLike]):
    """A copy of ``model`` with the named parameters replaced; works on traced values (the fitter calls it).

    Args:
        model: a brdf model.
        values: ``name -> array``, names as in ``model.fittable()``.

    Returns:
        The new model.
    """
    if not values:
        return model
    names = list(values)

    def where(m):
        leaves = []
        for name in names:
            obj = m
            for part in name.split("."):
                obj = _resolve(obj, part)
            leaves.append(obj)
        return leaves

    get_params(model, names)  # validates the names with a clear error
    return eqx.tree_at(where, model, [jnp.asarray(values[n]) for n in names], is_leaf=lambda x: x is None)


# ---------------------------------------------------------------------------
# Validation helpers (concrete values only: traced values are never inspected)


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def as_param(owner: str, name: str, x: ArrayLike, lower: float | None = None, upper: float | None = None,
             lower_open: bool = False) -> Array:
    """Convert a parameter to an array and, when it is concrete, check its range.

    Raises ValueError naming ``owner.name`` when a value is NaN/Inf or outside
    [lower, upper] (or (lower, upper] when ``lower_open``).
    """
    if x is None:
        raise ValueError(f"{owner}: parameter {name!r} is None")
    arr = jnp.asarray(x)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    if _is_concrete(arr):
        v = np.asarray(arr)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{owner}: parameter {name!r} has non-finite values")
        if lower is not None:
            bad = v <= lower if lower_open else v < lower
            if np.any(bad):
                rel = ">" if lower_open else ">="
                raise ValueError(f"{owner}: parameter {name!r} must be {rel} {lower}, got min {v.min()}")
        if upper is not None and np.any(v > upper):
            raise ValueError(f"{owner}: parameter {name!r} must be <= {upper}, got max {v.max()}")
    return arr


def check_directions(owner: str, wi, wo) -> tuple[Array, Array]:
    """Arrays of shape [*batch, 3] with the same rank (their batch axes must broadcast)."""
    wi = jnp.asarray(wi)
    wo = jnp.asarray(wo)
    for nm, w in (("wi", wi), ("wo", wo)):
        if w.ndim < 1 or w.shape[-1] != 3:
            raise ValueError(f"{owner}: {nm} must have shape [*batch, 3], got {w.shape}")
    if wi.ndim != wo.ndim:
        raise ValueError(f"{owner}: wi and wo must have the same rank, got {wi.shape} and {wo.shape}")
    return wi, wo


def check_param_rank(owner: str, ndim: int, **params) -> None:
    """Each parameter must be 0-d or have the directions' rank ``ndim``."""
    for name, p in params.items():
        if p is None:
            continue
        if p.ndim not in (0, ndim):
            raise ValueError(
                f"{owner}: parameter {name!r} has shape {p.shape}; with directions of rank {ndim} "
                f"it must be 0-d or have rank {ndim} ([*batch, C] or [*batch, 1])"
            )


def cos_theta(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """cos of the angle to the normal, keeping a length-1 channel axis."""
    return w[..., 2:3]



def check_module_rank(module: eqx.Module, ndim: int) -> None:
    """Every array leaf of ``module`` must be 0-d or have the directions' rank ``ndim``.

    Raises ValueError naming the leaf's path, e.g. ``Microfacet.distribution.alpha_x``.
    """
    leaves = jax.tree_util.tree_leaves_with_path(module)
    for path, leaf in leaves:
        if not hasattr(leaf, "ndim"):
            continue
        if leaf.ndim not in (0, ndim):
            name = type(module).__name__ + jax.tree_util.keystr(path)
            raise ValueError(
                f"parameter {name} has shape {leaf.shape}; with directions of rank {ndim} it must "
                f"be 0-d or have rank {ndim} ([*batch, C] or [*batch, 1])"
            )
