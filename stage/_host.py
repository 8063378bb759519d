"""Surfaces held on the host: cutting a surface into blocks without a JAX program per block.

``Surface.subset`` gathers with ``jnp`` (it works under tracing), and an eager JAX
gather compiles once per new shape: a stream of blocks with different sample
counts would compile (and keep) a program per block. These helpers index NumPy
copies of the fields and hand the result to JAX with ``jax.device_put``, which
compiles nothing."""

from __future__ import annotations

import jax
import numpy as np

from ._surface import Surface

_FIELDS = ("position", "normal", "tangent", "bitangent", "uv", "area", "texel_index", "face", "barycentric")


def host_fields(surface: Surface) -> dict:
    """The surface's fields as NumPy arrays (views of the JAX buffers on CPU: no copy)."""
    return {k: None if getattr(surface, k) is None else np.asarray(getattr(surface, k)) for k in _FIELDS}


def host_subset(fields: dict, resolution, index) -> Surface:
    """``Surface.subset`` of a surface held as :func:`host_fields`, with no JAX computation."""
    return Surface(**{k: None if v is None else jax.device_put(v[index]) for k, v in fields.items()},
                   resolution=tuple(resolution))
