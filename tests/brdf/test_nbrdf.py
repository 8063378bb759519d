"""NBRDF (Sztrajman et al. 2021) networks of the MERL materials: the input encoding
against an independent port of the authors' coordinates, the forward pass against
a NumPy Keras forward, the loader's errors, the property checks (non-negativity,
reciprocity to the network's accuracy, energy), the MERL-table round trip and the
known looks of gold, blue acrylic and white fabric. Skipped without ../shared/data."""

import json

import h5py
import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np
import pytest

import brdf
from brdf._nbrdf import NBRDF, directional_albedo_half, load_nbrdf, nbrdf_encoding, nbrdf_names
from tests.brdf._util import edge_case_pairs, ev, fjit

FOLDER_PART = ("measured_brdf", "merl_nbrdf")
# The 80 networks of ../shared/data/measured_brdf (README.md).
N_MATERIALS = 80

# Reciprocity bounds (the network is reciprocal only to its fit of the MERL data: it sees
# phi_d over [0, 2 pi) and learnt the symmetric targets independently on both halves).
# Measured on 20000 uniform pairs, float32, over all 80 (docs/measured_brdf.md): the worst
# per-material median of |log(1 + f(wi, wo)) - log(1 + f(wo, wi))| is 2.1e-3 and the worst 99th
# percentile 0.072; the bounds leave about 2x.
RECIPROCITY_LOG_MEDIAN = 5e-3
RECIPROCITY_LOG_P99 = 0.15
# Lower bound on that asymmetry: the documented lack of exact reciprocity (like Phong's) is real.
RECIPROCITY_LOG_MIN = 1e-5
# Energy: directional albedo <= 1 (measured over all 80, half-vector quadrature: at most 0.71).
ALBEDO_MAX = 1.0


@pytest.fixture
def folder(shared_data):
    f = shared_data.joinpath(*FOLDER_PART)
    if not f.is_dir():
        pytest.skip(f"NBRDF networks not found at {f}")
    return f


def _one(folder, name):
    return load_nbrdf(folder / f"{name}.h5")


# ---- an independent port of the authors' coordinates (Neural-BRDF binary_to_nbrdf/coords.py) ----
def _rotate(v, axis, angle):
    """Rodrigues' rotation of v [N, 3] about a unit axis [3] by angle [N]."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + axis * (v @ axis)[:, None] * (1 - c) + np.cross(axis, v) * s


def _authors_encoding(wi, wo):
    h = wi + wo
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    theta_h = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    d = _rotate(_rotate(wi, np.array([0.0, 0.0, 1.0]), -phi_h), np.array([0.0, 1.0, 0.0]), -theta_h)
    return np.concatenate([np.stack([np.sin(theta_h), 0 * theta_h, np.cos(theta_h)], 1), d], 1)


def _keras_forward(path, x):
    """Dense(relu) -> Dense(relu) -> Dense(linear) -> exp(x) - 1, straight from the HDF5 file."""
    with h5py.File(path, "r") as f:
        w = [(f[f"dense_{i}/dense_{i}/kernel:0"][()], f[f"dense_{i}/dense_{i}/bias:0"][()]) for i in (1, 2, 3)]
    y = x
    for i, (k, b) in enumerate(w):
        y = y @ k.astype(np.float64) + b.astype(np.float64)
        if i < 2:
            y = np.maximum(y, 0.0)
    return np.expm1(y)


def test_folder_holds_every_material(folder):
    names = nbrdf_names(folder)
    assert len(names) == N_MATERIALS
    for n in ("gold-metallic-paint", "blue-acrylic", "white-fabric", "chrome-steel"):
        assert n in names


def test_encoding_matches_authors_coordinates(key):
    wi, wo = brdf.check.random_pairs(key, 2000)
    ours = np.asarray(nbrdf_encoding(wi, wo))
    ref = _authors_encoding(np.asarray(wi), np.asarray(wo))
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    # both vectors are unit and h sits at phi_h = 0
    np.testing.assert_allclose(np.linalg.norm(ours[:, :3], axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(ours[:, 3:], axis=1), 1.0, atol=1e-12)
    assert np.all(ours[:, 1] == 0) and np.all(ours[:, 0] >= 0)


def test_forward_matches_keras_port(folder, key):
    path = folder / "gold-metallic-paint.h5"
    m = load_nbrdf(path)
    wi, wo = brdf.check.random_pairs(key, 512)
    ours = np.asarray(ev(m, wi, wo))
    ref = np.maximum(_keras_forward(path, _authors_encoding(np.asarray(wi), np.asarray(wo))), 0.0)
    # float32 weights evaluated in float64 on both sides: agreement to rounding
    np.testing.assert_allclose(ours, ref, rtol=1e-10, atol=1e-12)
    # by name through the folder lookup, the same network
    m2 = load_nbrdf("gold-metallic-paint", folder=folder)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(m), jax.tree_util.tree_leaves(m2),
                                                     strict=True))


def test_loader_errors_name_the_file(folder, tmp_path):
    with pytest.raises(ValueError, match="nope.h5"):
        load_nbrdf(tmp_path / "nope.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    with pytest.raises(ValueError, match="junk.h5"):
        load_nbrdf(junk)
    partial = tmp_path / "partial.h5"
    with h5py.File(partial, "w") as f:
        f["dense_1/dense_1/kernel:0"] = np.zeros((6, 21), np.float32)
        f["dense_1/dense_1/bias:0"] = np.zeros(21, np.float32)
    with pytest.raises(ValueError, match="partial.h5.*dense_2"):
        load_nbrdf(partial)
    shapes = tmp_path / "shapes.h5"
    with h5py.File(shapes, "w") as f:
        for i, (k, b) in enumerate([((5, 21), 21), ((21, 21), 21), ((21, 3), 3)], 1):
            f[f"dense_{i}/dense_{i}/kernel:0"] = np.zeros(k, np.float32)
            f[f"dense_{i}/dense_{i}/bias:0"] = np.zeros(b, np.float32)
    with pytest.raises(ValueError, match="shapes.h5.*chain"):
        load_nbrdf(shapes)
    # a good network beside an architecture that is not NBRDF's
    good = tmp_path / "good.h5"
    good.write_bytes((folder / "gold-paint.h5").read_bytes())
    cfg = json.loads((folder / "gold-paint.json").read_text())
    cfg["config"]["layers"][1]["config"]["activation"] = "tanh"
    good.with_suffix(".json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="good.h5.*activations"):
        load_nbrdf(good)
    # built directly: the shape check (or, first, the jaxtyping checker the suite runs under)
    with pytest.raises((ValueError, jaxtyping.TypeCheckError)):
        NBRDF(jnp.zeros((6, 4)), jnp.zeros(4), jnp.zeros((4, 4)), jnp.zeros(4), jnp.zeros((4, 2)), jnp.zeros(3))


def test_nonnegative_finite_and_stable_every_material(folder, key):
    wi, wo = edge_case_pairs(key, 4096, jnp.float32)
    worst = np.inf
    for name in nbrdf_names(folder):
        m = _one(folder, name)
        worst = min(worst, float(brdf.check.min_value(m, wi, wo)))
    assert worst >= 0.0  # the clamp of exp(y) - 1 < 0 holds for all 80
    # values, direction gradients and weight gradients finite at the edge cases (float64)
    wi64, wo64 = edge_case_pairs(key, 1024)
    for name in ("chrome-steel", "white-fabric"):
        s = brdf.check.stability(_one(folder, name), wi64, wo64)
        assert s == {"value": True, "grad_directions": True, "grad_params": True, "nonnegative": True}, name
    # zero below the horizon on either side
    up = jnp.asarray([[0.3, 0.0, 0.954]])
    down = jnp.asarray([[0.3, 0.0, -0.954]])
    m = _one(folder, "white-fabric")
    assert float(jnp.max(ev(m, up, down))) == 0.0 and float(jnp.max(ev(m, down, up))) == 0.0


@fjit
def _log_asymmetry(m, wi, wo):
    a, b = m(wi, wo), m(wo, wi)
    return jnp.abs(jnp.log1p(a) - jnp.log1p(b))


def test_reciprocity_to_the_networks_accuracy(folder, key):
    wi, wo = brdf.check.random_pairs(key, 20000, jnp.float32)
    med, p99 = [], []
    for name in nbrdf_names(folder):
        lg = np.asarray(_log_asymmetry(_one(folder, name), wi, wo))
        med.append(np.median(lg))
        p99.append(np.percentile(lg, 99))
    med, p99 = np.asarray(med), np.asarray(p99)
    assert med.max() < RECIPROCITY_LOG_MEDIAN, med.max()
    assert p99.max() < RECIPROCITY_LOG_P99, p99.max()
    # not exactly reciprocal (documented): every network has some asymmetry
    assert np.mean(med > RECIPROCITY_LOG_MIN) > 0.5 and p99.min() > 10 * RECIPROCITY_LOG_MIN


def test_half_vector_albedo_against_the_wi_quadrature_and_a_mirror():
    c = np.cos(np.linspace(0.05, 1.3, 5))
    wo = jnp.asarray(np.stack([np.sqrt(1 - c * c), 0 * c, c], -1))
    rough = brdf.Microfacet(brdf.GGX(jnp.asarray(0.3)), brdf.SchlickFresnel(jnp.asarray(1.0)), "smith")
    a_h = np.asarray(directional_albedo_half(rough, wo))
    a_i = np.asarray(brdf.check.directional_albedo(rough, wo, over="wo"))
    # two quadratures of the same reciprocal integral
    np.testing.assert_allclose(a_h, a_i, rtol=2e-3)
    # a near-mirror (alpha 0.003, F = 1) reflects everything away from grazing: G ~ 1
    mirror = brdf.Microfacet(brdf.GGX(jnp.asarray(0.003)), brdf.SchlickFresnel(jnp.asarray(1.0)), "smith")
    np.testing.assert_allclose(np.asarray(directional_albedo_half(mirror, wo[:4])), 1.0, atol=1e-3)


def test_energy_albedo_at_most_one(folder):
    c = np.cos(np.linspace(0.02, 1.45, 6))
    wo = jnp.asarray(np.stack([np.sqrt(1 - c * c), 0 * c, c], -1), jnp.float32)
    alb = jax.jit(directional_albedo_half)
    # the brightest diffuse, a glossy and a mirror-like metal (docs/measured_brdf.md lists all 80)
    for name in ("white-fabric", "white-diffuse-bball", "gold-metallic-paint", "chrome"):
        a = np.asarray(alb(_one(folder, name), wo))
        assert np.all(a >= 0) and a.max() <= ALBEDO_MAX, (name, a.max())


def test_merl_round_trip_at_grid_points(folder, tmp_path, key):
    m = _one(folder, "gold-metallic-paint")
    table = brdf.tabulate_merl(m, dtype=jnp.float64)
    path = tmp_path / "gold.binary"
    from relight.io import write_merl  # the writer lives in relight.io (brdf writes no files)

    write_merl(path, table)
    back = brdf.read_merl(path)
    # the file holds the table (scales applied and removed in float64)
    np.testing.assert_allclose(np.asarray(back.table), np.asarray(table), rtol=1e-12)
    # nearest lookup at bin centres (random phi_h: the network is isotropic) = the network
    th, td, pd = (np.asarray(a) for a in brdf.merl_bin_centers(jnp.float64))
    k = jax.random.split(key, 4)
    n = 4000
    ih, id_, ip = (np.asarray(jax.random.randint(kk, (n,), 0, r)) for kk, r in zip(k[:3], (90, 90, 180), strict=True))
    ph = np.asarray(jax.random.uniform(k[3], (n,), minval=-np.pi, maxval=np.pi))
    wi, wo = brdf.half_diff_to_directions(th[ih], ph, td[id_], pd[ip])
    got = np.asarray(ev(back, wi, wo))
    want = np.asarray(ev(m, wi, wo))
    # the table's bins hold the network at their centres: equal to float64 rounding (the
    # directions rebuilt from angles at phi_h != 0 differ by ~1 ulp; in float32 the same
    # ulps move a mirror peak by up to 3.5e-3 relative, docs/measured_brdf.md)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    # below-horizon bins are 0 in the file (and read back as 0)
    assert float(np.min(np.asarray(back.table))) >= 0.0


def _looks(m):
    """(specular [3] at theta_h = 0, theta_d = 30 deg; off-specular diffuse [3]) in 1/sr."""
    th = np.deg2rad(30.0)
    wo = jnp.asarray([[np.sin(th), 0.0, np.cos(th)]])
    spec = np.asarray(ev(m, jnp.asarray([[-np.sin(th), 0.0, np.cos(th)]]), wo))[0]
    s40, c40 = np.sin(np.deg2rad(40.0)), np.cos(np.deg2rad(40.0))
    diff = np.asarray(ev(m, jnp.asarray([[0.0, s40, c40]]), wo))[0]
    return spec, diff


def test_known_looks(folder):
    spec, _ = _looks(_one(folder, "gold-metallic-paint"))
    assert spec[0] > spec[1] > spec[2] and spec[2] < 0.5 * spec[0], spec  # yellow highlight
    _, diff = _looks(_one(folder, "blue-acrylic"))
    assert diff[2] > diff[1] > diff[0] and diff[2] > 2 * diff[0], diff  # blue body
    spec, diff = _looks(_one(folder, "blue-acrylic"))
    assert spec.min() > 0.5 * spec.max() and spec.min() > 100 * diff.max(), spec  # white clear-coat highlight
    # white fabric: diffuse (no highlight: the mirror direction within 10% of off-specular) and
    # bright, but not grey in MERL: warm, B/R ~ 0.46 (docs/measured_brdf.md)
    spec, diff = _looks(_one(folder, "white-fabric"))
    assert np.all(np.abs(spec / diff - 1) < 0.1), (spec, diff)
    assert diff[0] > diff[1] > diff[2] and 0.3 < diff[2] / diff[0] < 0.6, diff
    # a near-grey diffuse white: teflon, channels within 10%
    _, diff = _looks(_one(folder, "teflon"))
    assert diff.max() / diff.min() < 1.1 and diff.min() > 0.08, diff


def test_simulator_takes_the_network(folder):
    import stage

    m = _one(folder, "gold-metallic-paint")
    rig = stage.light_stage_x()
    rig = stage.Rig(position=rig.position[:8], intensity=rig.intensity[:8], solid_angle=rig.solid_angle[:8],
                    near_field=rig.near_field)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=64, height=64)
    z = np.linspace(0.5, 1.0, 6)
    nrm = np.stack([np.sqrt(1 - z * z), 0 * z, z], 1)
    t = np.stack([z, 0 * z, -np.sqrt(1 - z * z)], 1)
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    surf = stage.Surface(position=f(50 * nrm), normal=f(nrm), tangent=f(t), bitangent=f(np.cross(nrm, t)),
                         uv=f(np.zeros((6, 2))), area=f(np.ones(6)), texel_index=jnp.arange(6),
                         face=jnp.zeros(6, jnp.int32), resolution=(1, 6))
    cap = stage.simulate(surf, rig, [cam], m, np.ones((6, 8), bool), np.ones((1, 6), bool))
    wi, wo, irr = stage.shading_directions(surf, rig, cam.center)
    want = m(wi, jnp.broadcast_to(wo, wi.shape)) * jnp.maximum(wi[..., 2:3], 0.0) * irr
    got = np.where(np.asarray(cap.mask[0])[..., None], np.asarray(cap.radiance[0]), 0.0)
    np.testing.assert_allclose(got, np.where(np.asarray(cap.mask[0])[..., None], np.asarray(want), 0.0),
                               rtol=1e-5, atol=1e-9)
    # Six samples, and the first layer's leading axis is 6 too: chunks of 4
    # samples must not slice the network (NBRDF.per_sample is False).
    got = np.zeros(cap.radiance.shape, np.float32)
    for v, ls, ps, rad, _ in stage.simulate_chunks(surf, rig, [cam], m, np.ones((6, 8), bool),
                                                   np.ones((1, 6), bool), sample_chunk=4):
        got[v, ls, ps] = np.asarray(rad)
    np.testing.assert_allclose(got, np.asarray(cap.radiance), rtol=1e-6, atol=1e-12)
