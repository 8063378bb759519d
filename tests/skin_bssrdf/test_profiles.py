"""All profiles: closed-form totals against quadrature, monotone fall-off, gradients
at r = 0 and at albedo 0 and 1, jit/vmap/eager agreement, model-specific checks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skin_bssrdf as sb
from tests.helpers import assert_close, assert_finite, fjit
from tests.skin_bssrdf.quadrature import integrate_disc

ALBEDOS = jnp.array([0.0, 0.1, 0.5, 0.9, 0.99])  # reduced albedo alpha' (0 and ~1 are the edges)
ST = 1.3  # sigma_t' in 1/mm


def make(name, albedo):
    a = jnp.asarray(albedo)
    if name == "dipole":
        return sb.Dipole((1 - a) * ST, a * ST, 1.3)
    if name == "better_dipole":
        return sb.BetterDipole((1 - a) * ST, a * ST, 1.4)
    if name == "burley":
        return sb.Burley(a, 0.7)
    if name == "gaussians":
        # d'Eon's red-channel Gaussians, one "channel" per albedo
        w = jnp.asarray(sb._gaussians.DEON2007_WEIGHTS)[:, :1] * jnp.atleast_1d(a)[None, :]
        return sb.SumOfGaussians(w, jnp.asarray(sb._gaussians.DEON2007_VARIANCES))
    if name == "multipole":
        # absorbing enough that 6 pairs converge (truncation ~1e-7); thickness > 1/sigma_t'
        return sb.Multipole((1 - a) * ST + 0.05, a * ST, 2.0, 1.3, 1.4, n_pairs=6)
    raise KeyError(name)


PROFILES = ["dipole", "better_dipole", "burley", "gaussians", "multipole"]



@pytest.mark.parametrize("name", PROFILES)
def test_total_equals_quadrature(name):
    # quadrature of 2 pi r R_d(r) equals total() to 1e-4 absolute (total() is a reflectance), for a range of albedos
    p = make(name, ALBEDOS)
    quad, total, cumulative = fjit(lambda p: (integrate_disc(p, r_max=1e3), p.total(), p.cumulative(1e3)))(p)
    assert_close(quad, total, rtol=0, atol=1e-4)
    # and the closed-form cumulative energy agrees with the quadrature to a finite radius
    assert_close(cumulative, total, rtol=0, atol=1e-4)


@pytest.mark.parametrize("name", PROFILES)
def test_falls_monotonically_and_non_negative(name):
    p = make(name, ALBEDOS[1:])  # alpha' = 0 is identically zero
    r = jnp.linspace(0.0, 20.0, 2001)
    R = np.asarray(p.radial(r))
    assert np.all(R >= 0)
    # strictly decreasing until it underflows to 0
    d = np.diff(R, axis=0)
    assert np.all((d < 0) | (R[1:] == 0))


@pytest.mark.parametrize("name", PROFILES)
def test_gradients_finite_at_edges_and_match_finite_differences(name):
    def f(a, r):
        p = make(name, a)
        return jnp.sum(p.radial(r + jnp.array([0.0, 0.05, 0.5, 2.0]))) + jnp.sum(p.total())

    fg = fjit(jax.value_and_grad(f, argnums=(0, 1)))  # f and its gradient: one program
    r0 = jnp.array(0.0)
    # finite at r = 0 and at albedo 0 and 1
    for a in (0.0, 1.0):
        assert_finite(*fg(jnp.array(a), r0))
    # float64 central differences (h = 1e-6: O(h^2) truncation + rounding/h ~ 1e-10)
    a, h = jnp.array(0.7), 1e-6
    fd = (fg(a + h, r0)[0] - fg(a - h, r0)[0]) / (2 * h)
    assert_close(fg(a, r0)[1][0], fd, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("name", PROFILES)
def test_jit_vmap_eager_agree(name):
    p = make(name, jnp.array([0.3, 0.8, 0.95]))
    r = jnp.linspace(0.0, 4.0, 9)
    eager = p.radial(r)
    both = jax.jit(jax.vmap(lambda q, r: q.radial(r), in_axes=(None, 0)))(p, r)  # jit of vmap
    assert_close(both, eager)


# --- model-specific ---------------------------------------------------------------


def test_fresnel_moments_against_polynomial_fdr():
    # 2 C_1 is the diffuse Fresnel reflectance; Jensen's polynomial fit is quoted accurate to ~1e-3
    eta = jnp.linspace(1.0, 2.0, 11)
    c1, c2 = sb.fresnel_moments(eta)
    assert_close(2 * c1, sb.fresnel_diffuse_reflectance(eta), rtol=0, atol=3e-3)
    assert_close(c1[0], 0.0, atol=1e-14)  # eta = 1: no reflection
    assert np.all(np.diff(np.asarray(c2)) > 0)
    # against brute-force quadrature of the Fresnel term in mu (1e5 midpoints)
    mu = (np.arange(100000) + 0.5) / 100000
    e = 1.4
    st2 = e**2 * (1 - mu**2)
    ct = np.sqrt(np.clip(1 - st2, 0, 1))
    rs = (e * mu - ct) / (e * mu + ct)
    rp = (mu - e * ct) / (mu + e * ct)
    F = np.where(st2 >= 1, 1.0, 0.5 * (rs**2 + rp**2))
    c1, c2 = sb.fresnel_moments(e)
    assert_close(c1, np.mean(F * mu), rtol=1e-6)  # midpoint rule with a sqrt kink at the critical angle
    assert_close(c2, np.mean(F * mu**2), rtol=1e-6)


def test_better_and_classical_dipole_agree_and_differ():
    a = jnp.array([0.3, 0.9, 0.99, 1.0])
    c = sb.Dipole(1 - a, a, 1.3)
    b = sb.BetterDipole(1 - a, a, 1.3)
    # agree: no absorption -> every photon leaves, both give 1; near it within 1 %
    assert_close(b.total()[3], 1.0)
    assert_close(c.total()[3], 1.0)
    assert_close(b.total()[2], c.total()[2], rtol=0.01)
    # differ where d'Eon shows they do: with strong absorption the better dipole (alpha'^2
    # source, Grosjean D) reflects much less; at alpha' = 0.3 less than a third as much
    assert float(b.total()[0]) < float(c.total()[0]) / 3
    # and near the source: the mixed fluence/flux boundary makes R(0) differ by > 30 %
    R0c, R0b = c.radial(0.0), b.radial(0.0)
    assert np.all(np.abs(np.asarray(R0b / R0c) - 1) > 0.3)


def test_multipole_thick_slab_is_the_dipole():
    sa, ss = jnp.array([0.032, 0.17, 0.48]), jnp.array([0.74, 0.88, 1.01])
    m = sb.Multipole(sa, ss, 200.0, eta=1.3, eta_bottom=1.3, n_pairs=3)
    d = sb.Dipole(sa, ss, 1.3)
    r = jnp.array([0.0, 0.5, 3.0, 10.0])
    assert_close(m.radial(r), d.radial(r), rtol=1e-10, atol=1e-14)
    assert_close(m.total(), d.total(), rtol=1e-10)
    assert_close(m.total_transmittance(), 0.0, atol=1e-12)


def test_multipole_matches_1d_slab_solution_and_conserves_energy():
    sa, ss = jnp.array([0.02, 0.2]), jnp.array([1.5, 1.5])
    m = sb.Multipole(sa, ss, 1.0, 1.3, 1.4, n_pairs=40)
    R0, T0 = m.total_untruncated()
    assert_close(m.total(), R0, rtol=1e-9)
    assert_close(m.total_transmittance(), T0, rtol=1e-9)
    assert np.all(np.asarray(m.truncation()) < 1e-9)
    # the transmittance profile integrates to its total too (quadrature, 1e-4 as for R)
    class _T:
        def radial(self, r):
            return m.transmittance(r)

    assert_close(integrate_disc(_T()), T0, atol=1e-4, rtol=0)
    # nothing absorbed: R + T = alpha' = 1 (the 1-D solution's limit)
    m0 = sb.Multipole(0.0, 1.5, 1.0, 1.3, 1.4)
    R, T = m0.total_untruncated()
    assert_close(R + T, 1.0, rtol=1e-12)
    # thinner slab lets more through
    assert float(sb.Multipole(0.05, 1.5, 1.0).total_untruncated()[1][0]) > float(
        sb.Multipole(0.05, 1.5, 3.0).total_untruncated()[1][0]
    )


def test_multipole_rejects_slab_thinner_than_a_transport_mfp():
    with pytest.raises(ValueError, match="thickness"):
        sb.Multipole(0.1, 0.9, 0.5)  # 1/sigma_t' = 1 mm > 0.5 mm


def test_burley_normalised_and_fits():
    p = sb.Burley.from_mean_free_path(jnp.array([0.2, 0.5, 0.9]), 1.0, "searchlight")
    assert_close(p.total(), [0.2, 0.5, 0.9])
    # the paper's fits (eqs. 5, 6, 8) at A = 0.8
    assert_close(sb.SCALE_FITS["searchlight"](0.8), 1.05)
    assert_close(sb.SCALE_FITS["diffuse"](0.8), 1.1)
    assert_close(sb.SCALE_FITS["dmfp"](0.33), 3.5)
    assert_close(p.d, 1.0 / sb.SCALE_FITS["searchlight"](jnp.array([0.2, 0.5, 0.9])))
    with pytest.raises(ValueError, match="config"):
        sb.Burley.from_mean_free_path(0.5, 1.0, "bogus")


def test_burley_against_dipole_family_reported_figure():
    # Christensen & Burley fitted their shape to Monte Carlo references, not to dipoles:
    # the dipoles are bounded at r = 0 where Burley's profile is 1/r. The best-fitting d
    # (over a grid) still leaves a relative L1 distance of the radial energy densities
    # 2 pi r R(r) of 17-54 % (docs/skin_bssrdf.md); here the bound for alpha' >= 0.9.
    from tests.skin_bssrdf.quadrature import nodes

    r, w = nodes()
    a = jnp.array([0.9, 0.99])
    ref = sb.BetterDipole(1 - a, a, 1.3)
    p1 = 2 * np.pi * r[:, None] * np.asarray(ref.radial(jnp.asarray(r)))
    ds = np.geomspace(0.05, 10, 120)

    def burley(total, d):
        return sb.Burley(total, d).radial(jnp.asarray(r))

    best = []
    for c in range(2):
        errs = [
            np.sum(np.abs(p1[:, c] - 2 * np.pi * r * np.asarray(burley(ref.total()[c], d))[:, 0]) * w)
            / np.sum(p1[:, c] * w)
            for d in ds
        ]
        best.append(min(errs))
    assert max(best) < 0.40
    assert min(best) > 0.2  # and the shapes really differ (the figure is not an artefact)


def test_deon_skin_gaussians():
    p = sb.SumOfGaussians.skin_deon2007()
    assert_close(p.total(), jnp.ones(3), atol=1e-12)  # published weights are normalised
    # red scatters farthest: its 50 % energy radius is the largest
    r50 = np.asarray(sb.energy_radius(p, 0.5))
    assert r50[0] > r50[1] > r50[2]
    p2 = sb.SumOfGaussians.skin_deon2007(jnp.array([0.6, 0.4, 0.3]))
    assert_close(p2.total(), [0.6, 0.4, 0.3])


def test_fit_sum_of_gaussians_to_dipole():
    d = sb.preset("skin1")
    fit = sb.fit_sum_of_gaussians(d, n=6)
    assert_close(fit.total(), d.total(), rtol=1e-10)  # energy held exactly
    from tests.skin_bssrdf.quadrature import nodes

    r, w = nodes(r_max=60.0)
    a = 2 * np.pi * r[:, None] * np.asarray(d.radial(jnp.asarray(r)))
    b = 2 * np.pi * r[:, None] * np.asarray(fit.radial(jnp.asarray(r)))
    l1 = np.sum(np.abs(a - b) * w[:, None], 0) / np.sum(a * w[:, None], 0)
    assert np.all(l1 < 0.03), l1  # six Gaussians: ~1 % (d'Eon et al. report a similar fit quality)


def test_energy_radius():
    d = sb.preset("skin1")
    r = sb.energy_radius(d, 0.9)
    frac = np.array([float(d.cumulative(r[c])[c] / d.total()[c]) for c in range(3)])
    assert_close(frac, 0.9, rtol=1e-9)


def test_single_scattering_white_furnace_and_reciprocity(key):
    # eta = 1, isotropic, no absorption: directional albedo = (1 - mu ln(1 + 1/mu))/2 (closed form)
    d = sb.Dipole(0.0, 1.0, 1.0, 0.0)
    x, wq = np.polynomial.legendre.leggauss(32)
    mu, wmu = 0.5 * (x + 1), 0.5 * wq
    phi = np.linspace(0, 2 * np.pi, 9)[:-1]  # isotropic, eta = 1: the integrand does not depend on phi
    M, PH = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M**2)
    wo = np.stack([s * np.cos(PH), s * np.sin(PH), M], -1)
    for mi in (1.0, 0.3):
        wi = np.broadcast_to([np.sqrt(1 - mi**2), 0, mi], wo.shape)
        f = np.asarray(d.single_scattering(jnp.asarray(wi), jnp.asarray(wo)))[..., 0]
        albedo = np.sum(f * M * wmu[:, None]) * 2 * np.pi / 8
        assert_close(albedo, 0.5 * (1 - mi * np.log(1 + 1 / mi)), rtol=1e-8)  # 32-point Gauss-Legendre
    # reciprocity with Fresnel, anisotropy and absorption
    d = sb.Dipole(jnp.array([0.1, 0.5]), 1.0, 1.4, 0.8)
    k1, k2 = jax.random.split(key)
    a = jax.random.normal(k1, (50, 3))
    b = jax.random.normal(k2, (50, 3))
    a = a.at[:, 2].set(jnp.abs(a[:, 2])) / jnp.linalg.norm(a, axis=1, keepdims=True)
    b = b.at[:, 2].set(jnp.abs(b[:, 2])) / jnp.linalg.norm(b, axis=1, keepdims=True)
    assert_close(d.single_scattering(a, b), d.single_scattering(b, a))
    assert_close(d.single_scattering(jnp.array([0.0, 0.0, -1.0]), jnp.array([0.0, 0.0, 1.0])), 0.0)


@pytest.mark.parametrize(
    "ctor, match",
    [
        (lambda: sb.BetterDipole(0.1, 1.0, 5.0), "eta"),
        (lambda: sb.Burley(1.2, 1.0), "albedo"),
        (lambda: sb.Burley(0.5, 0.0), "d \\(shape"),
        (lambda: sb.SumOfGaussians(jnp.ones((2, 3)), jnp.array([1.0, -1.0])), "variances"),
        (lambda: sb.SumOfGaussians(jnp.ones((3, 3)), jnp.array([1.0, 2.0])), "weights must have shape"),
        (lambda: sb.Multipole(0.1, 1.0, 2.0, n_pairs=-1), "n_pairs"),
        (lambda: sb.preset("jelly"), "unknown material"),
    ],
)
def test_invalid_input_raises(ctor, match):
    with pytest.raises(ValueError, match=match):
        ctor()
