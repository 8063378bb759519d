"""The lighting-pattern autoencoder (Kang et al. 2018, "Efficient Reflectance
Capture Using an Autoencoder", SIGGRAPH, sec. 4).

Encoder: the linear pattern layer. Pattern k lights light l at weight
W[k, l] = sigmoid(theta[k, l]) in [0, 1] (physically realisable: no negative
light, no light above full power), the same for every colour channel; its
measurement of a lumitexel m [L, C] is, by linearity of light,

    y[k, c] = sum_l W[k, l] m[l, c]                                    (Kang eq. 1)

and the camera adds noise per pattern frame (``sensor_noise``: shot + read
noise of a ``stage.Sensor`` at its per-frame exposure, Gaussian with the
sensor's variance so the noise is differentiable in W).

Decoders (small MLPs, equinox) read the measurements normalised by what the
same patterns give on a white Lambertian at the sample's known geometry,
q[k, c] = y[k, c] / (sum_l W[k, l] white[l, c]) (= rho_d for a Lambertian
sample, whatever its normal or position), compressed by asinh, together with
the geometry the light stage knows from its scan (normal, view direction,
position), and with a roughness ``grid`` the closed-form specular features of
``grid_features`` (the measurements' least-squares fit at each grid roughness).
One decodes the material (rho_d [3], Schlick F0 = rho_s, GGX
alpha); the other the grey lumitexel, in units of the sample's mean white
OLAT radiance, compressed by asinh (Kang's lumitexel decoder; here a side
output that also shapes the patterns).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

import stage

from ..fitting._spd import spd_solve

# The decoder's roughness range: the fitter's prior floor (relight.ALPHA_FIT_MIN) up to the ladder's ALPHA_MAX.
ALPHA_DECODE_MIN = 0.02
ALPHA_DECODE_MAX = 1.0
# The white-Lambertian normaliser is floored at this fraction of the sample's
# brightest pattern: a pattern whose lit lights all sit below the horizon
# measures ~0 and must not divide noise by ~0.
_WHITE_FLOOR = 1e-2


class PatternAutoencoder(eqx.Module):
    """``logits`` [K, L] (patterns = sigmoid(logits)), the material decoder
    ``material_mlp`` (features -> 5: rho_d logits [3], rho_s logit, alpha
    logit) and the lumitexel decoder ``lumitexel_mlp`` (features -> L)."""

    logits: Float[Array, "pattern light"]
    material_mlp: eqx.nn.MLP
    lumitexel_mlp: eqx.nn.MLP
    grid: tuple[float, ...] = eqx.field(static=True, default=())

    def __init__(self, key, num_patterns: int, num_lights: int, *, width: int = 192, depth: int = 3,
                 lumitexel_width: int = 192, lumitexel_depth: int = 2, init_scale: float = 2.0,
                 grid: tuple[float, ...] = ()):
        """Random logits N(0, init_scale^2) and MLPs (ReLU, ``width`` x ``depth``
        hidden layers) with equinox's default initialisation. ``grid``: roughnesses
        of the closed-form specular features (``grid_features``; () = none)."""
        if num_patterns < 1 or num_lights < 1:
            raise ValueError(f"PatternAutoencoder: num_patterns and num_lights must be >= 1, "
                             f"got {num_patterns}, {num_lights}")
        k1, k2, k3 = jax.random.split(key, 3)
        self.logits = init_scale * jax.random.normal(k1, (num_patterns, num_lights), jnp.float32)
        self.grid = tuple(float(a) for a in grid)
        n_in = num_patterns * 3 + 9 + 5 * len(self.grid)
        # float32 networks whatever jax_enable_x64 says: the decoder computes in float32.
        self.material_mlp = eqx.nn.MLP(n_in, 5, width, depth, activation=jax.nn.relu, dtype=jnp.float32, key=k2)
        self.lumitexel_mlp = eqx.nn.MLP(n_in, num_lights, lumitexel_width, lumitexel_depth, activation=jax.nn.relu,
                                        dtype=jnp.float32, key=k3)

    @property
    def num_patterns(self) -> int:
        return self.logits.shape[0]

    @property
    def patterns(self) -> Float[Array, "pattern light"]:
        """The lighting patterns W [K, L], every weight in [0, 1]."""
        return jax.nn.sigmoid(self.logits)

    def measure(self, radiance: Float[Array, "*batch light channel"]) -> Float[Array, "*batch pattern channel"]:
        """Noise-free pattern measurements y[k, c] = sum_l W[k, l] m[l, c] (Kang eq. 1)."""
        return measure(self.patterns, radiance)

    def features(self, y: Float[Array, "sample pattern channel"], white: Float[Array, "sample light channel"],
                 geometry: Float[Array, "sample 9"], bases=None) -> Float[Array, "sample feature"]:
        """The decoders' input: asinh of y over the patterns' white-Lambertian
        response (module docstring), flattened, the geometry [n, wo, p / 200 mm]
        and, with a ``grid``, :func:`grid_features` of ``bases`` [N, L, C, 2J]
        (``relight.patterns.specular_bases`` at the grid's roughnesses)."""
        W = self.patterns.astype(white.dtype)
        g = measure(W, white)
        floor = _WHITE_FLOOR * jnp.max(g, axis=(1, 2), keepdims=True) + 1e-30
        gf = jnp.maximum(g, floor)
        y = jnp.asarray(y, g.dtype)
        q = y / gf
        parts = [jnp.arcsinh(q).reshape(q.shape[0], -1), jnp.asarray(geometry, g.dtype)]
        if self.grid:
            if bases is None:
                raise ValueError("PatternAutoencoder.features: a model with a roughness grid needs 'bases'")
            gb = jnp.einsum("kl,nlcb->nkcb", W, jnp.asarray(bases, g.dtype))
            parts.append(grid_features(y, gf, gb))
        return jnp.concatenate(parts, axis=-1)

    def decode(self, y, white, geometry, bases=None) -> dict[str, Array]:
        """Decoded material per sample from measurements y [N, K, C]: {"rho_d"
        [N, 3], "rho_s" [N] (F0), "alpha" [N] in [ALPHA_DECODE_MIN, ALPHA_DECODE_MAX],
        "lumitexel" [N, L] (asinh of the grey lumitexel over the mean white OLAT radiance)}."""
        x = self.features(y, white, geometry, bases)
        dt = x.dtype
        o = jax.vmap(self.material_mlp)(x.astype(jnp.float32)).astype(dt)
        lumi = jax.vmap(self.lumitexel_mlp)(x.astype(jnp.float32)).astype(dt)
        alpha = ALPHA_DECODE_MIN + (ALPHA_DECODE_MAX - ALPHA_DECODE_MIN) * jax.nn.sigmoid(o[:, 4])
        # The F0 logit starts 3 below 0 (F0 ~ 0.05, skin-like) rather than at 0.5.
        return {"rho_d": jax.nn.sigmoid(o[:, :3]), "rho_s": jax.nn.sigmoid(o[:, 3] - 3.0), "alpha": alpha,
                "lumitexel": lumi}


def grid_features(y: Float[Array, "sample pattern channel"], white: Float[Array, "sample pattern channel"],
                  bases: Float[Array, "sample pattern channel basis"]) -> Float[Array, "sample feature"]:
    """Closed-form fits of the pattern measurements at each grid roughness alpha_j, differentiable in the patterns.

    The model y[k, c] = rho_c white[k, c] + F0 A_j[k, c] + B_j[k, c] is linear in (rho_r, rho_g, rho_b, F0)
    (``specular_bases``), so each is a 4-unknown least-squares solve (normal equations, a ridge of 10 ulps of the
    trace). What the relight fitter's roughness-grid start computes.

    Args:
        y: measurements [N, K, C].
        white: a white Lambertian sample's measurements [N, K, C].
        bases: the specular bases measured [N, K, C, 2J].

    Returns:
        Features [N, 5J]: per j the solution and the log relative residual.
    """
    A, B = bases[..., 0::2], bases[..., 1::2]  # [N, K, C, J]
    s = jnp.mean(white, axis=(1, 2), keepdims=True)  # one scale per sample: ~unit entries
    w, A, B, r = white / s, A / s[..., None], B / s[..., None], (y / s)[..., None] - B / s[..., None]
    m_cc = jnp.sum(w * w, axis=1)  # [N, C]
    m_c3 = jnp.sum(w[..., None] * A, axis=1)  # [N, C, J]
    m_33 = jnp.sum(A * A, axis=(1, 2))  # [N, J]
    b_c = jnp.sum(w[..., None] * r, axis=1)  # [N, C, J]
    b_3 = jnp.sum(A * r, axis=(1, 2))  # [N, J]
    N, C, J = m_c3.shape
    eye = jnp.eye(C, dtype=w.dtype)
    top = jnp.concatenate([jnp.broadcast_to((m_cc[:, :, None] * eye[None])[:, None], (N, J, C, C)),
                           jnp.swapaxes(m_c3, 1, 2)[..., None]], axis=-1)  # [N, J, C, C+1]
    bottom = jnp.concatenate([jnp.swapaxes(m_c3, 1, 2), m_33[..., None]], axis=-1)[:, :, None]  # [N, J, 1, C+1]
    M = jnp.concatenate([top, bottom], axis=2)
    tr = jnp.trace(M, axis1=-2, axis2=-1)[..., None, None]
    eye4 = jnp.eye(C + 1, dtype=w.dtype)[None, None]
    # A ridge of 10 ulps of the trace: keeps the float32 solve finite when the lobe
    # basis is collinear with the white one (a lobe too broad to tell from albedo).
    M = M + (10.0 * float(jnp.finfo(w.dtype).eps) * tr + 1e-30) * eye4
    rhs = jnp.concatenate([jnp.swapaxes(b_c, 1, 2), b_3[..., None]], axis=-1)  # [N, J, C+1]
    x = spd_solve(M, rhs)
    res = r - (w[..., None] * jnp.swapaxes(x[..., :C], 1, 2)[:, None] + A * x[:, None, None, :, C])
    rel = jnp.sqrt(jnp.sum(res * res, axis=(1, 2)) / (jnp.sum((y / s) ** 2, axis=(1, 2))[:, None] + 1e-30))
    feats = jnp.concatenate([jnp.clip(x, -1.0, 2.0), jnp.log(rel + 1e-4)[..., None]], axis=-1)  # [N, J, 5]
    return feats.reshape(N, -1)


def measure(patterns: Float[Array, "pattern light"],
            radiance: Float[Array, "*batch light channel"]) -> Float[Array, "*batch pattern channel"]:
    """Pattern measurements of lumitexels, y[..., k, c] = sum_l W[k, l] m[..., l, c].

    Args:
        patterns: light weights W [K, L].
        radiance: lumitexels m [*batch, L, C].

    Returns:
        Measurements [*batch, K, C].

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder", eq. 1.
    """
    radiance = jnp.asarray(radiance)
    return jnp.einsum("kl,...lc->...kc", jnp.asarray(patterns, radiance.dtype), radiance)


def sensor_noise(key, y: Float[Array, "*batch channel"], sensor: stage.Sensor) -> Float[Array, "*batch channel"]:
    """Measurements plus Gaussian noise of the sensor's variance per frame, in radiance units.

    The variance of ``stage.Sensor``: shot noise (exposure x y photo-electrons) if enabled, read noise,
    quantisation; std = sqrt(Var[DN]) gain / (wb exposure). Differentiable in y (reparameterised), so the patterns
    learn the noise they will meet.

    Args:
        key: a ``jax.random`` key.
        y: measurements [*batch, C].
        sensor: the camera sensor.

    Returns:
        Noisy measurements [*batch, C].
    """
    y = jnp.asarray(y)
    var_dn = sensor.variance(jnp.maximum(y, 0.0))
    # Radiance per DN: gain / (wb exposure), read off the sensor's own inverse.
    per_dn = sensor.to_radiance(jnp.ones_like(y) + jnp.asarray(sensor.black_level, y.dtype))
    std = jnp.sqrt(var_dn) * per_dn
    return y + std * jax.random.normal(key, y.shape, y.dtype)


def lumitexel_target(radiance: Float[Array, "sample light channel"],
                     white: Float[Array, "sample light channel"]) -> Float[Array, "sample light"]:
    """The lumitexel decoder's target: asinh of the grey lumitexel over the sample's mean white OLAT radiance.

    Args:
        radiance: lumitexels [N, L, C].
        white: a white Lambertian sample's lumitexels [N, L, C] (the mean is over its lit lights).

    Returns:
        Targets [N, L].
    """
    grey = jnp.mean(radiance, axis=-1)
    w = jnp.mean(white, axis=-1)
    s = jnp.sum(w, axis=1, keepdims=True) / jnp.maximum(jnp.sum(w > 0, axis=1, keepdims=True), 1).astype(w.dtype)
    return jnp.arcsinh(grey / jnp.maximum(s, 1e-30))
