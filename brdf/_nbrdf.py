"""Neural BRDFs: the per-material MLPs of Sztrajman, Rainer, Ritschel & Weyrich,
"Neural BRDF Representation and Importance Sampling", CGF 40(6), 2021 (NBRDF),
each trained on one measured material of the MERL database (Matusik et al. 2003).

The network (their ``binary_to_nbrdf.py``; the Keras files' JSON): input the
6-D Rusinkiewicz encoding x = (h_x, h_y, h_z, d_x, d_y, d_z) with the half vector
taken at phi_h = 0, h = (sin theta_h, 0, cos theta_h), and d the difference
vector (wi rotated by -phi_h about the normal, then by -theta_h about the
bitangent: MERL's convention, :func:`brdf.half_diff_coords`); two hidden Dense
layers of 21 ReLU units; a linear Dense layer of 3; then a Lambda layer
y -> exp(y) - 1, the inverse of the log(1 + f) the training loss compares in
(their ``mean_absolute_logarithmic_error`` on f cos(theta_i)). The output is
f_r in 1/sr per RGB channel: the training targets are MERL's stored values
times the channel scales (``brdf.MERL_SCALE``), i.e. what ``brdf.read_merl``
returns. exp(y) - 1 is negative where y < 0: those lanes are clamped to 0 (the
data are non-negative; the clamp moves them by less than the network's error).

The network sees phi_d over the whole circle, but the MERL data it learnt are
symmetric under phi_d -> phi_d + pi (reciprocity: swapping wi and wo turns d
into -d at the same h), so the network is reciprocal only to its fitting
accuracy; docs/measured_brdf.md measures by how much.
"""

from __future__ import annotations

import base64
import json
import os
from pathlib import Path
from typing import ClassVar

import h5py
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._base import AbstractBRDF, ParamSpec, check_directions, cos_theta
from ._check import hemisphere_quadrature
from ._merl import half_diff_coords
from ._safe import widest_float, working_float

# The bundled networks: 6 inputs, 21 + 21 ReLU units, 3 outputs (675 weights).
NBRDF_INPUTS = 6
NBRDF_OUTPUTS = 3
_LAYERS = ("dense_1", "dense_2", "dense_3")
_ACTIVATIONS = ("relu", "relu", "linear")
# Where the project keeps the 80 MERL networks (../shared/data next to the repository checkout);
# the environment variable overrides it.
NBRDF_DIR_ENV = "LIGHTSTAGE_NBRDF_DIR"
_DEFAULT_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "measured_brdf" / "merl_nbrdf"


def nbrdf_folder() -> Path:
    """The folder :func:`load_nbrdf` looks names up in: ``$LIGHTSTAGE_NBRDF_DIR``, else
    ``../shared/data/measured_brdf/merl_nbrdf`` beside the repository."""
    env = os.environ.get(NBRDF_DIR_ENV)
    return Path(env) if env else _DEFAULT_DIR


def nbrdf_names(folder: str | os.PathLike | None = None) -> list[str]:
    """Sorted material names (file stems of ``*.h5``) in an NBRDF folder.

    Args:
        folder: the folder (None: ``nbrdf_folder()``).

    Returns:
        The names; empty when the folder is absent.
    """
    folder = nbrdf_folder() if folder is None else Path(folder)
    return sorted(p.stem for p in folder.glob("*.h5")) if folder.is_dir() else []


def nbrdf_encoding(wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch 6"]:
    """The NBRDF network's input (h_x, h_y, h_z, d_x, d_y, d_z) for direction pairs.

    The half vector at phi_h = 0, (sin theta_h, 0, cos theta_h), and the difference vector
    (sin theta_d cos phi_d, sin theta_d sin phi_d, cos theta_d), the angles from ``brdf.half_diff_coords`` (d is wi
    in the half vector's frame).

    Args:
        wi, wo: unit directions [*batch, 3] in the shading frame.

    Returns:
        The encoding [*batch, 6].

    References:
        Sztrajman et al. 2021, "Neural BRDF representation and importance sampling"; Rusinkiewicz 1998,
        "A new change of variables for efficient BRDF representation".
    """
    theta_h, _, theta_d, phi_d = half_diff_coords(wi, wo)
    st = jnp.sin(theta_d)
    return jnp.stack([jnp.sin(theta_h), jnp.zeros_like(theta_h), jnp.cos(theta_h),
                      st * jnp.cos(phi_d), st * jnp.sin(phi_d), jnp.cos(theta_d)], axis=-1)


class NBRDF(AbstractBRDF):
    """A measured isotropic BRDF as a neural network (NBRDF, Sztrajman et al. 2021):
    f_r = max(0, exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1) per RGB channel,
    x = :func:`nbrdf_encoding` (wi, wo); 1/sr, 0 below the horizon.

    ============  ===================  ========================================
    field         shape                meaning
    ============  ===================  ========================================
    kernel_1      [6, H]               first Dense layer (Keras ``dense_1``)
    bias_1        [H]
    kernel_2      [H, H]               second Dense layer (``dense_2``)
    bias_2        [H]
    kernel_3      [H, 3]               linear output layer (``dense_3``)
    bias_3        [3]
    ============  ===================  ========================================

    The weights are array leaves (``jax.grad`` reaches them) but not fittable
    parameters: a measurement is not refitted here (``fittable()`` is empty).
    They are not per-sample parameters either: one network is one material, so
    the model broadcasts over any batch of directions. Reciprocal and
    energy-conserving only to the network's accuracy (docs/measured_brdf.md).
    """

    per_sample: ClassVar[bool] = False  # one network for every sample
    kernel_1: Float[Array, "6 hidden1"]
    bias_1: Float[Array, " hidden1"]
    kernel_2: Float[Array, "hidden1 hidden2"]
    bias_2: Float[Array, " hidden2"]
    kernel_3: Float[Array, "hidden2 3"]
    bias_3: Float[Array, " 3"]

    def __check_init__(self):
        k1, b1, k2, b2, k3, b3 = (self.kernel_1, self.bias_1, self.kernel_2, self.bias_2, self.kernel_3, self.bias_3)
        shapes = tuple(tuple(getattr(a, "shape", ())) for a in (k1, b1, k2, b2, k3, b3))
        ok = (len(shapes[0]) == 2 and shapes[0][0] == NBRDF_INPUTS and shapes[1] == shapes[0][1:]
              and len(shapes[2]) == 2 and shapes[2][0] == shapes[0][1] and shapes[3] == shapes[2][1:]
              and len(shapes[4]) == 2 and shapes[4] == (shapes[2][1], NBRDF_OUTPUTS) and shapes[5] == (NBRDF_OUTPUTS,))
        if not ok:
            raise ValueError(f"NBRDF: layer shapes {shapes} do not chain 6 -> H1 -> H2 -> 3 "
                             "(kernel_1 [6, H1], bias_1 [H1], kernel_2 [H1, H2], bias_2 [H2], kernel_3 [H2, 3], "
                             "bias_3 [3])")

    def network(self, x: Float[Array, "*batch 6"]) -> Float[Array, "*batch 3"]:
        """The raw network output exp(y) - 1 (may be slightly negative) for encoded inputs x."""
        dt = x.dtype

        def dense(v, kernel, bias):  # float32 weights, evaluated in the inputs' dtype; rank kept explicit
            b = jnp.reshape(jnp.asarray(bias, dt), (1,) * (v.ndim - 1) + (-1,))
            return jnp.einsum("...i,ij->...j", v, jnp.asarray(kernel, dt)) + b

        h = jnp.maximum(dense(x, self.kernel_1, self.bias_1), 0.0)
        h = jnp.maximum(dense(h, self.kernel_2, self.bias_2), 0.0)
        return jnp.expm1(dense(h, self.kernel_3, self.bias_3))

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """f_r(wi, wo) in 1/sr, [*batch, 3] (RGB), no cosine factor; 0 at or below the horizon."""
        wi, wo = check_directions("NBRDF", wi, wo)
        dt = working_float(widest_float(wi, wo))
        wi, wo = wi.astype(dt), wo.astype(dt)
        wi, wo = jnp.broadcast_arrays(wi, wo)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        f = jnp.maximum(self.network(nbrdf_encoding(wi, wo)), 0.0)  # exp(y) - 1 < 0 where y < 0: clamped
        return jnp.where(active, f, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """None: measured data are not fitted."""
        return {}


def _resolve_path(path_or_name, folder) -> Path:
    p = Path(path_or_name)
    if p.suffix == ".h5" or p.is_file() or p.parent != Path("."):
        return p if p.suffix == ".h5" or p.is_file() else p.with_suffix(".h5")
    return (nbrdf_folder() if folder is None else Path(folder)) / f"{p.name}.h5"


def _check_json(path: Path, h5_path: Path) -> None:
    """The Keras architecture beside the weights, when present, must be the NBRDF one:
    Dense relu, Dense relu, Dense linear, Lambda exp(x) - 1."""
    try:
        cfg = json.loads(path.read_text(encoding="utf-8"))
        layers = cfg["config"]["layers"] if isinstance(cfg["config"], dict) else cfg["config"]
        kinds = [layer["class_name"] for layer in layers]
        acts = tuple(layer["config"].get("activation") for layer in layers if layer["class_name"] == "Dense")
        lam = [layer["config"] for layer in layers if layer["class_name"] == "Lambda"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"load_nbrdf({h5_path}): cannot read its architecture {path}: {e}") from e
    if kinds != ["Dense", "Dense", "Dense", "Lambda"] or acts != _ACTIVATIONS:
        raise ValueError(f"load_nbrdf({h5_path}): {path} describes layers {kinds} with activations {acts}, "
                         f"not NBRDF's Dense x 3 {_ACTIVATIONS} + Lambda")
    # The Lambda is marshalled Python bytecode (never loaded here); its names must include K.exp.
    fn = lam[0].get("function")
    code = fn[0] if isinstance(fn, list) and fn else fn
    try:
        raw = base64.b64decode(code) if isinstance(code, str) else b""
    except ValueError:
        raw = b""
    if b"exp" not in raw:
        raise ValueError(f"load_nbrdf({h5_path}): the Lambda layer of {path} is not NBRDF's exp(x) - 1")


def load_nbrdf(path_or_name: str | os.PathLike, folder: str | os.PathLike | None = None) -> NBRDF:
    """Load an NBRDF network from its Keras HDF5 weights, as float32 arrays.

    The weights are layers ``dense_1..3``, each ``<layer>/<layer>/kernel:0`` and ``bias:0``. The ``.json``
    architecture beside the file, when present, is checked to be the NBRDF one (Dense relu, relu, linear, Lambda
    exp - 1).

    Args:
        path_or_name: a ``.h5`` path, or a material name (``"gold-metallic-paint"``) looked up in ``folder``.
        folder: where names are looked up (None: ``nbrdf_folder()``).

    Returns:
        The ``NBRDF`` model.

    Raises:
        ValueError: naming the file, when it is missing, not HDF5, lacks a layer, has shapes that do not chain
            6 -> H -> H -> 3, or holds non-finite weights.

    References:
        Sztrajman et al. 2021, "Neural BRDF representation and importance sampling".
    """
    path = _resolve_path(path_or_name, folder)
    if not path.is_file():
        raise ValueError(f"load_nbrdf({path}): no such file")
    arrays = {}
    try:
        with h5py.File(path, "r") as f:
            for layer in _LAYERS:
                group = f.get(f"{layer}/{layer}")
                if group is None:
                    raise ValueError(f"load_nbrdf({path}): no layer {layer!r} (found {sorted(f.keys())})")
                for part in ("kernel", "bias"):
                    ds = group.get(f"{part}:0")
                    if ds is None:
                        raise ValueError(f"load_nbrdf({path}): layer {layer!r} has no {part}:0")
                    arrays[f"{part}_{layer[-1]}"] = np.asarray(ds[()], np.float32)
    except OSError as e:
        raise ValueError(f"load_nbrdf({path}): not a readable HDF5 file ({e})") from e
    bad = [k for k, v in arrays.items() if not np.all(np.isfinite(v))]
    if bad:
        raise ValueError(f"load_nbrdf({path}): non-finite weights in {bad}")
    side = path.with_suffix(".json")
    if side.is_file():
        _check_json(side, path)
    shapes = {k: v.shape for k, v in arrays.items()}
    h1 = shapes["kernel_1"][-1] if shapes["kernel_1"] else -1
    h2 = shapes["kernel_2"][-1] if shapes["kernel_2"] else -1
    want = {"kernel_1": (NBRDF_INPUTS, h1), "bias_1": (h1,), "kernel_2": (h1, h2), "bias_2": (h2,),
            "kernel_3": (h2, NBRDF_OUTPUTS), "bias_3": (NBRDF_OUTPUTS,)}
    if shapes != want:
        raise ValueError(f"load_nbrdf({path}): layer shapes {shapes} do not chain 6 -> H1 -> H2 -> 3")
    return NBRDF(**{k: jnp.asarray(v) for k, v in arrays.items()})


# Breaks of the theta_h panels (radians): measured specular peaks (MERL's chrome, a few
# mrad wide) sit at theta_h = 0 for every wo, so panels this close to the normal resolve them.
HALF_BREAKS = (0.002, 0.006, 0.02, 0.06, 0.2, 0.5)


def directional_albedo_half(model, wo: Float[Array, "M 3"], n_theta: int = 24, n_phi: int = 64,
                            breaks=HALF_BREAKS) -> Float[Array, "M C"]:
    """Directional albedo a(wo) = integral f_r(wi, wo) cos(theta_i) dwi, integrated over the half vector.

    The white-furnace quantity of ``brdf.check.directional_albedo``, with wi = 2 (wo.h) h - wo and
    dwi = 4 (wo.h) dh, on ``brdf.check.hemisphere_quadrature`` panels at ``breaks`` in theta_h. It resolves lobes
    that peak at h = n, however narrow, for every wo (a wi-quadrature misses MERL's mirror-like metals).

    Args:
        model: one material (parameters 0-d or [C]).
        wo: unit outgoing directions [M, 3].
        n_theta, n_phi: quadrature points per theta_h panel and in phi_h.
        breaks: the panel boundaries in theta_h.

    Returns:
        Albedo [M, C].

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 14 (the half-vector
        Jacobian).
    """
    wo = jnp.atleast_2d(jnp.asarray(wo))
    h, w_h = hemisphere_quadrature(n_theta, n_phi, breaks, dtype=wo.dtype)

    def one(w1):
        c = h @ w1  # wo.h [N]
        wi = 2.0 * c[:, None] * h - w1[None, :]
        ok = (c > 0) & (wi[:, 2] > 0)
        f = jnp.reshape(model(wi, jnp.broadcast_to(w1, wi.shape)), (wi.shape[0], -1))
        jac = jnp.where(ok, 4.0 * c * wi[:, 2] * w_h, 0.0)
        return jnp.sum(f * jac[:, None], axis=0)

    return jax.lax.map(one, wo)
