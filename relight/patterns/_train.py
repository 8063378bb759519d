"""Training the pattern autoencoder with optax (Adam, warm-up + cosine
schedule, global-norm clipping), on lumitexels simulated afresh for every
step (``simulate_lumitexels``: no data set to overfit, deterministic from the
seed), and saving / loading a trained model (patterns through
``stage.save_patterns``, the decoders with equinox serialisation, both atomic).

Loss per batch (Kang et al. 2018 sec. 4.2 decode the lumitexel; here also the
material, as the fit path needs a start):

    L = mean (ln rho_d' - ln rho_d)^2 + mean ((rho_s' - rho_s) / 0.05)^2
        + mean_{rho_s > 0.005} (ln alpha' - ln alpha)^2
        + lumitexel_weight * mean (lumi' - asinh(grey lumitexel / mean white))^2

with the measurements taken through ``sensor_noise`` (one noise draw per
pattern frame and step).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

import stage

from ..results import atomic_write_bytes, atomic_write_text
from ._autoencoder import PatternAutoencoder, lumitexel_target, sensor_noise
from ._lumitexels import ALPHA_GRID, TRAIN_RANGES, Lumitexels, ParameterRanges, simulate_lumitexels, specular_bases

# Below this F0 a sample has no lobe to speak of: its roughness is not in the loss.
_LOBE_MIN = 0.005
# F0 errors are scored in units of this (a typical dielectric F0 spread).
_F0_SCALE = 0.05


class TrainConfig(eqx.Module):
    """Training settings: ``steps``, ``batch`` (lumitexels per step),
    peak learning rate ``lr`` after ``warmup`` linear steps, cosine decay to
    ``lr * final_fraction``; ``clip`` global gradient norm; ``lumitexel_weight``;
    ``seed``; the material / geometry ``ranges``; network ``width`` / ``depth``;
    ``grid``: roughnesses of the decoder's closed-form specular features
    (default ``ALPHA_GRID``; () = none, the plain decoder)."""

    steps: int = eqx.field(static=True, default=3000)
    batch: int = eqx.field(static=True, default=256)
    lr: float = eqx.field(static=True, default=3e-3)
    warmup: int = eqx.field(static=True, default=100)
    final_fraction: float = eqx.field(static=True, default=0.03)
    clip: float = eqx.field(static=True, default=1.0)
    lumitexel_weight: float = eqx.field(static=True, default=0.5)
    seed: int = eqx.field(static=True, default=0)
    ranges: ParameterRanges = eqx.field(static=True, default=TRAIN_RANGES)
    width: int = eqx.field(static=True, default=192)
    depth: int = eqx.field(static=True, default=3)
    grid: tuple[float, ...] = eqx.field(static=True, default=ALPHA_GRID)

    def __check_init__(self):
        if self.steps < 1 or self.batch < 1 or not self.lr > 0:
            raise ValueError(f"TrainConfig: steps and batch must be >= 1 and lr > 0, got "
                             f"{self.steps}, {self.batch}, {self.lr}")


def loss_terms(model: PatternAutoencoder, lumi: Lumitexels, key, sensor: stage.Sensor, rig: stage.Rig | None = None
               ) -> dict:
    """The loss terms of the module docstring for one batch (noise seeded by
    ``key``); ``rig`` is needed for a model with a roughness grid (its bases)."""
    y = sensor_noise(key, model.measure(lumi.radiance), sensor)
    bases = None
    if model.grid:
        if rig is None:
            raise ValueError("loss_terms: a model with a roughness grid needs the 'rig'")
        bases = specular_bases(rig, lumi.position, lumi.normal, lumi.tangent, lumi.bitangent, lumi.wo,
                               lumi.visible, model.grid)
    out = model.decode(y, lumi.white, lumi.geometry(), bases)
    dt = y.dtype
    rho = jnp.mean((jnp.log(out["rho_d"] + 1e-4) - jnp.log(lumi.rho_d + 1e-4)) ** 2)
    f0 = jnp.mean(((out["rho_s"] - lumi.rho_s) / _F0_SCALE) ** 2)
    lobe = (lumi.rho_s > _LOBE_MIN).astype(dt)
    alpha = jnp.sum(lobe * (jnp.log(out["alpha"]) - jnp.log(lumi.alpha)) ** 2) / jnp.maximum(jnp.sum(lobe), 1.0)
    lt = jnp.mean((out["lumitexel"] - lumitexel_target(lumi.radiance, lumi.white)) ** 2)
    return {"rho_d": rho, "rho_s": f0, "alpha": alpha, "lumitexel": lt}


def total_loss(terms: dict, lumitexel_weight: float):
    """The weighted sum of ``loss_terms``."""
    return terms["rho_d"] + terms["rho_s"] + terms["alpha"] + lumitexel_weight * terms["lumitexel"]


@functools.lru_cache(maxsize=16)
def make_optimizer(config: TrainConfig) -> optax.GradientTransformation:
    """Adam with global-norm clipping and a warm-up + cosine learning-rate schedule.
    One object per config (cached): the jitted step takes it as a static
    argument, so trainings with equal configs share one compilation."""
    warmup = max(1, min(config.warmup, config.steps - 1))
    schedule = optax.warmup_cosine_decay_schedule(0.0, config.lr, warmup, max(config.steps, warmup + 1),
                                                  config.lr * config.final_fraction)
    return optax.chain(optax.clip_by_global_norm(config.clip), optax.adam(schedule))


@eqx.filter_jit
def _step(model, opt_state, rig, camera_center, sensor, key, config: TrainConfig, optimizer):
    k_data, k_noise = jax.random.split(key)
    lumi = simulate_lumitexels(k_data, rig, camera_center, config.batch, config.ranges)

    def f(m):
        terms = loss_terms(m, lumi, k_noise, sensor, rig)
        return total_loss(terms, config.lumitexel_weight), terms

    (loss, terms), grads = eqx.filter_value_and_grad(f, has_aux=True)(model)
    # optax's Adam raises its betas to the int32 step count, a promotion that
    # jax_numpy_dtype_promotion="strict" (the test suite's) refuses: standard rules for the update only.
    with jax.numpy_dtype_promotion("standard"):
        updates, opt_state = optimizer.update(grads, opt_state, eqx.filter(model, eqx.is_inexact_array))
    model = eqx.apply_updates(model, updates)
    return model, opt_state, loss, terms


def train(rig: stage.Rig, camera_center, num_patterns: int, sensor: stage.Sensor,
          config: TrainConfig | None = None, *, model: PatternAutoencoder | None = None, progress=None,
          log_every: int = 100):
    """Train a ``PatternAutoencoder`` of ``num_patterns`` patterns for ``rig``
    seen from ``camera_center`` [3] (mm) under ``sensor``'s per-frame noise.

    Returns (model, history): history a list of dicts {"step", "loss", and the
    loss terms} every ``log_every`` steps (means over those steps).
    Deterministic: the model's initialisation and every batch and noise draw
    come from ``config.seed``. ``progress(phase, done, total)`` (stage.Progress)
    counts steps in phase "train K patterns". ``config`` None: ``TrainConfig()``."""
    config = TrainConfig() if config is None else config
    key = jax.random.PRNGKey(config.seed)
    k_init, k_steps = jax.random.split(key)
    if model is None:
        model = PatternAutoencoder(k_init, num_patterns, rig.num_lights, width=config.width, depth=config.depth,
                                   grid=config.grid)
    elif model.logits.shape != (num_patterns, rig.num_lights):
        raise ValueError(f"train: argument 'model' has patterns {model.logits.shape}, expected "
                         f"{(num_patterns, rig.num_lights)}")
    optimizer = make_optimizer(config)
    opt_state = optimizer.init(eqx.filter(model, eqx.is_inexact_array))
    center = jnp.asarray(camera_center, jnp.float32)
    bar = stage.Phase(progress, f"train {num_patterns} patterns", config.steps)
    history, acc, n_acc = [], None, 0
    for step in range(config.steps):
        model, opt_state, loss, terms = _step(model, opt_state, rig, center, sensor,
                                              jax.random.fold_in(k_steps, step), config, optimizer)
        vals = {"loss": loss, **terms}
        acc = vals if acc is None else {k: acc[k] + vals[k] for k in acc}
        n_acc += 1
        if (step + 1) % log_every == 0 or step + 1 == config.steps:
            history.append({"step": step + 1, **{k: float(v) / n_acc for k, v in acc.items()}})
            acc, n_acc = None, 0
            bar.advance(min(log_every, config.steps - bar.done))
    return model, history


def save_model(path, model: PatternAutoencoder, rig: stage.Rig, *, metadata: dict | None = None) -> None:
    """Write ``path``.patterns.json (``stage.save_patterns``: the file a rig
    plays, with ``metadata``) and ``path``.eqx (the whole model, equinox
    leaves) plus ``path``.json (its shape: patterns, lights, width, depth), each atomically."""
    path = Path(path)
    meta = dict(metadata or {})
    stage.save_patterns(path.with_suffix(".patterns.json"), np.asarray(model.patterns), rig, metadata=meta)
    atomic_write_bytes(path.with_suffix(".eqx"), lambda fh: eqx.tree_serialise_leaves(fh, model))
    shape = {"num_patterns": model.num_patterns, "num_lights": int(model.logits.shape[1]),
             "width": model.material_mlp.width_size, "depth": model.material_mlp.depth,
             "lumitexel_width": model.lumitexel_mlp.width_size, "lumitexel_depth": model.lumitexel_mlp.depth,
             "grid": list(model.grid), "metadata": meta}
    atomic_write_text(path.with_suffix(".json"), json.dumps(shape, indent=1) + "\n")


def load_model(path) -> tuple[PatternAutoencoder, dict]:
    """(model, metadata) written by ``save_model`` (``path`` without suffix)."""
    path = Path(path)
    shape = stage.read_json(path.with_suffix(".json"), "pattern-autoencoder description")
    if not isinstance(shape, dict):
        raise ValueError(f"{path.with_suffix('.json')}: not a pattern-autoencoder description (not an object)")
    try:
        like = PatternAutoencoder(jax.random.PRNGKey(0), int(shape["num_patterns"]), int(shape["num_lights"]),
                                  width=int(shape["width"]), depth=int(shape["depth"]),
                                  lumitexel_width=int(shape["lumitexel_width"]),
                                  lumitexel_depth=int(shape["lumitexel_depth"]),
                                  grid=tuple(float(a) for a in shape.get("grid", ())))
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path.with_suffix('.json')}: not a pattern-autoencoder description ({e})") from None
    with open(path.with_suffix(".eqx"), "rb") as fh:
        model = eqx.tree_deserialise_leaves(fh, like)
    return model, dict(shape.get("metadata", {}))
