"""Stability sweep of ``relight.fit_subsurface``: where the mean-free-path fit fails.

    python scripts/stability_subsurface.py                  # the full sweep (per="region")
    python scripts/stability_subsurface.py --per texel      # the per-texel fit
    python scripts/stability_subsurface.py --quick          # a 2 x 2 smoke run (~1.5 min, to a temp folder)

Scene: a flat 15 x 3.75 mm strip of skin (z = 0, facing the camera) at the
centre of the Light Stage X, between two 4 mm walls along its short ends
(x = +-7.5 mm; occluders only, not sampled), one camera 400 mm in front. A flat
strip, not a sphere or the head: the texel spacing is one number (strip /
resolution), no curvature confounds the blur, and the walls cast sharp shadow
edges parallel to them, at a distance set by each light's elevation (15..90
degrees land on the strip), so every part of the strip sees an irradiance step
under some light. A mean free path is only identifiable from spatial
irradiance variation: the step blurred by the profile is what the fit
measures; under uniform light the blur has nothing to act on.

Truth: ``stage.simulate`` with ``stage.Subsurface`` (Christensen-Burley
profile, ``Burley.from_mean_free_path(A, mfp, config="dmfp")``, A = (0.8, 0.6,
0.45), the same mfp in every channel, eta 1.4, the operator over every sample
pair on the strip) plus a GGX lobe (alpha 0.3, F0 0.03), all 346 lights, once
per true mfp on a 0.25 mm texel grid (``--sim-texel``). The fitted texels
(0.25, 0.75, 1.25 mm: odd multiples, so each coarse texel centre is a fine
one) are point samples of it: the coarse texel's radiance and validity are
those of the fine texel at its centre, as a texel resampled from finer photos
is. The 0.25 mm column therefore shares the simulation's grid (an inverse
crime: its error is a lower bound; the findings in the .md quantify it). The
"box" footprint instead averages the k x k fine texels (a texel valid where at
least half of its footprint is), as a texture filtered down would. Noise: shot
noise through ``stage.sense`` with a ``stage.Sensor`` whose exposure gives
the stated relative noise at the cell's median valid observation. Lights: the
Light Stage X (346), its 85 polarised lights (positions only; no polarisation
filters are simulated), and a 42-light farthest-point subset.

Fit: every panel but "BRDF stage" holds the specular lobe and normals at the
truth (an oracle BRDF stage, with the closed-form Lambert albedo that the
model choice compares against), so their failures are ``fit_subsurface``'s
own; "BRDF stage = relight.fit" runs ``relight.fit`` first, as the pipeline
does. The search bracket is widened to ``--mfp-range`` (0.01, 20) mm so that a
fit pinned at a bracket end cannot read as correct at the sweep's end values
(0.05 and 8 mm are the default bracket's ends); a texel-channel within 2% of a
bracket end counts as flagged. The baseline is 0.75 mm texels, 1% shot noise,
346 lights, the true lobe, point samples; each panel varies one of them.

Per cell: the median relative mfp error per channel over the *fitted*
texel-channels: those on the subsurface rung, not pinned at the bracket, and
``Fit.mfp_identified`` (the fitter's own flag: 1-sigma of ln mfp below 0.25;
for ``per="region"`` the region's shared value's) where the Fit has it; the
fraction flagged (every other texel-channel); and a verdict: ``ok`` (flagged
<= 50% and error <= 15% in every channel: issue 7's bar), ``biased`` (flagged
<= 50%, worst-channel error <= 50%), ``failed`` (otherwise, or a channel with
no fitted texel). The table also gives the error over every subsurface texel
with the flags ignored. Asserts that no fitted mfp is NaN or infinite.

Writes docs/figures/stability_subsurface.png (true mfp x texel size, noise,
lights, BRDF stage and texel footprint; colour = worst-channel median error,
x = failed, o = biased) and docs/figures/stability_subsurface.md (this setup,
the verdicts by condition and the table).
"""

from __future__ import annotations

import dataclasses
import inspect
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, parser

import brdf
import relight
import skin_bssrdf
import stage

FIG = Path(__file__).resolve().parent.parent / "docs" / "figures"

STRIP_MM = (15.0, 3.75)  # x (across the walls), y: a multiple of every texel spacing
WALL_MM = 4.0  # wall height: shadow edges from lights 15..90 degrees above the strip land on it
ALBEDO = (0.8, 0.6, 0.45)
F0, ALPHA, ETA = 0.03, 0.3, skin_bssrdf.SKIN_ETA
MFPS = tuple(float(x) for x in np.geomspace(0.05, 8.0, 7))
TEXELS = (0.25, 0.75, 1.25)  # odd multiples of the simulation grid: coarse centres are fine centres
NOISES = (0.0, 0.01, 0.05)
LIGHTS = (42, 85, 346)  # 85 = the Light Stage X's polarised set; others: farthest-point subsets
BRDFS = ("truth", "fit")
BASE = dict(texel=0.75, noise=0.01, lights=346, brdf="truth", footprint="point")
FOOTPRINTS = ("point", "box")
# Verdict thresholds (module docstring): issue 7's 15% bar, a factor-1.5 band beyond it, and coverage.
ERR_OK, ERR_BIASED, FLAGGED_FAILED = 0.15, 0.5, 0.5
PINNED_LOG = np.log(1.02)  # within 2% of a bracket end: the search hit the bracket, not a minimum


@dataclasses.dataclass(frozen=True)
class Cell:
    """One capture condition: texel spacing (mm), relative shot noise, light count, BRDF stage."""

    texel: float = BASE["texel"]
    noise: float = BASE["noise"]
    lights: int = BASE["lights"]
    brdf: str = BASE["brdf"]
    footprint: str = BASE["footprint"]


def sweep_cells() -> dict[str, list[Cell]]:
    """The panels of the figure: each varies one condition away from ``BASE``."""
    return {"texel": [Cell(texel=t) for t in TEXELS], "noise": [Cell(noise=n) for n in NOISES],
            "lights": [Cell(lights=n) for n in LIGHTS], "brdf": [Cell(brdf=b) for b in BRDFS],
            "footprint": [Cell(footprint=f) for f in FOOTPRINTS]}


# --------------------------------------------------------------------------- scene

def _grid(sx, sy, nx, ny):
    gx, gy = np.linspace(-sx / 2, sx / 2, nx + 1), np.linspace(-sy / 2, sy / 2, ny + 1)
    X, Y = np.meshgrid(gx, gy, indexing="xy")
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    uv = np.stack([(X.ravel() + sx / 2) / sx, (Y.ravel() + sy / 2) / sy], 1)
    idx = np.arange(v.shape[0]).reshape(ny + 1, nx + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    return v, np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]), uv


def trench_mesh(strip_mm=STRIP_MM, wall_mm: float = WALL_MM) -> stage.Mesh:
    """The strip (x, y in mm; UV-mapped, one chart) and two walls ``wall_mm`` high along its short ends
    (no UVs: never sampled)."""
    sx, sy = strip_mm
    v, f, uv = _grid(sx, sy, 8, 2)
    verts, faces, uvs, normals = [v], [f], [uv], [np.tile([0.0, 0.0, 1.0], (len(v), 1))]
    off = len(v)
    for xw in (-sx / 2 - 0.01, sx / 2 + 0.01):
        # Walls reach 5x beyond the strip in y, so their shadows on it are straight edges.
        verts.append(np.array([[xw, -5 * sy, 0], [xw, 5 * sy, 0], [xw, 5 * sy, wall_mm], [xw, -5 * sy, wall_mm]]))
        faces.append(np.array([[0, 1, 2], [0, 2, 3]]) + off)
        uvs.append(np.full((4, 2), -1.0))
        normals.append(np.tile([-np.sign(xw), 0.0, 0.0], (4, 1)))
        off += 4
    return stage.Mesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs),
                      "trench")


def strip_surface(mesh: stage.Mesh, texel_mm: float, strip_mm=STRIP_MM) -> stage.Surface:
    """Texel samples of the strip at spacing ``texel_mm`` (must divide the strip)."""
    nx, ny = (round(s / texel_mm) for s in strip_mm)
    if min(nx, ny) < 1 or not np.allclose([nx * texel_mm, ny * texel_mm], strip_mm):
        raise ValueError(f"texel_mm={texel_mm} must divide the strip {strip_mm} mm")
    return stage.texel_samples(mesh, (ny, nx))


def light_index(lsx: stage.Rig, n: int) -> np.ndarray:
    """Indices into the Light Stage X of ``n`` lights: all, the 85 polarised ones, or a farthest-point subset."""
    L = lsx.num_lights
    if n >= L:
        return np.arange(L)
    pos = np.asarray(lsx.position, np.float64)
    if n == 85:
        pol = np.asarray(stage.light_stage_x("polarized").position, np.float64)
        return np.sort(np.argmin(np.linalg.norm(pol[:, None] - pos[None], axis=-1), axis=1))
    d = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    pick = [int(np.argmax(d[:, 2]))]  # the light nearest the camera axis
    dist = 1 - d @ d[pick[0]]
    for _ in range(n - 1):
        k = int(np.argmax(dist))
        pick.append(k)
        dist = np.minimum(dist, 1 - d @ d[k])
    return np.sort(pick)


class Scene:
    """The strip, the rig, the camera and their visibility, and the simulated captures per true mfp (cached)."""

    def __init__(self, sim_texel: float = TEXELS[0], strip_mm=STRIP_MM, wall_mm: float = WALL_MM):
        self.strip = tuple(float(x) for x in strip_mm)
        self.mesh = trench_mesh(self.strip, wall_mm)
        self.sim_texel = float(sim_texel)
        self.fine = strip_surface(self.mesh, self.sim_texel, self.strip)
        self.rig = stage.light_stage_x()
        self.camera = stage.look_at((0.0, 0.0, 400.0), fov_deg=4, width=64, height=64)
        self.lv = stage.light_visibility(self.mesh, self.fine, self.rig)
        self.cv = stage.camera_visibility(self.mesh, self.fine, [self.camera])
        self._captures: dict[float, stage.Capture] = {}
        self._coarse: dict[float, tuple[stage.Surface, np.ndarray]] = {}

    def spec(self, P: int, dtype) -> brdf.Microfacet:
        """The true specular lobe (GGX, Smith, Schlick) on P samples."""
        return brdf.Microfacet(brdf.GGX(jnp.full((P, 1), ALPHA, dtype)),
                               brdf.SchlickFresnel(jnp.full((P, 1), F0, dtype)), "smith")

    def capture(self, mfp: float) -> stage.Capture:
        """The noise-free capture of the fine strip under all lights for a true mfp (mm, every channel)."""
        if mfp not in self._captures:
            surf = self.fine
            P = surf.num_samples
            A = jnp.broadcast_to(jnp.asarray(ALBEDO, jnp.float32), (P, 3))
            prof = skin_bssrdf.Burley.from_mean_free_path(A, jnp.full((P, 3), mfp, jnp.float32), config="dmfp")
            # Every pair on the strip: the truth's energy is cut by the strip's edges, not by the radius.
            op = skin_bssrdf.DiffusionOperator.build(np.asarray(surf.position), np.asarray(surf.area),
                                                     1.01 * float(np.hypot(*self.strip)), dtype=jnp.float32)
            cap = stage.simulate(surf, self.rig, [self.camera], self.spec(P, surf.position.dtype), self.lv, self.cv,
                                 subsurface=stage.Subsurface(prof, op, ETA))
            self._captures[mfp] = cap
        return self._captures[mfp]

    def coarse(self, texel: float, footprint: str = "point") -> tuple[stage.Surface, np.ndarray]:
        """(the strip at spacing ``texel``, the filter [Pc, Pf] from the fine texels to it): ``point``
        takes the fine texel at each coarse centre (an odd multiple: the centres coincide), ``box``
        averages the k x k fine texels of its footprint."""
        if (texel, footprint) not in self._coarse:
            k = round(texel / self.sim_texel)
            if not np.isclose(k * self.sim_texel, texel) or k < 1 or (footprint == "point" and k % 2 == 0):
                raise ValueError(f"texel {texel} mm must be an odd multiple of the simulation's {self.sim_texel} mm")
            if footprint not in FOOTPRINTS:
                raise ValueError(f"footprint must be one of {FOOTPRINTS}, got {footprint!r}")
            surf = strip_surface(self.mesh, texel, self.strip)
            ny, nx = self.fine.resolution
            r, c = np.divmod(np.asarray(self.fine.texel_index), nx)
            parent = np.searchsorted(np.asarray(surf.texel_index), (r // k) * (nx // k) + c // k)
            W = np.zeros((surf.num_samples, self.fine.num_samples))
            take = np.ones(len(r), bool) if footprint == "box" else (r % k == k // 2) & (c % k == k // 2)
            W[parent[take], np.arange(self.fine.num_samples)[take]] = 1.0
            self._coarse[(texel, footprint)] = (surf, W / W.sum(1, keepdims=True))
        return self._coarse[(texel, footprint)]


def observe(scene: Scene, mfp: float, cell: Cell, seed: int) -> tuple[stage.Capture, stage.Surface]:
    """The capture of ``cell``: lights subset, filtered to the cell's texels (``Scene.coarse``), shot noise."""
    cap = scene.capture(mfp)
    idx = light_index(scene.rig, cell.lights)
    surf, W = scene.coarse(cell.texel, cell.footprint)
    rad = np.einsum("qp,vlpc->vlqc", W, np.asarray(cap.radiance, np.float64)[:, idx])
    valid = np.einsum("qp,vlp->vlq", W, np.asarray(cap.mask, np.float64)[:, idx]) >= 0.5
    out = stage.Capture(jnp.asarray(rad, jnp.float32), jnp.asarray(valid), scene.rig.subset(idx), cap.cameras)
    if cell.noise > 0:
        # Shot noise: Poisson electrons; exposure e such that 1/sqrt(e L_ref) = noise at the median valid radiance.
        L_ref = float(np.median(rad[valid].mean(-1)))
        sensor = stage.Sensor(exposure=1.0 / (cell.noise ** 2 * L_ref), shot_noise=True)
        out = stage.sense(out, sensor, jax.random.PRNGKey(seed))
    return out, surf


def truth_fit(capture: stage.Capture, surface: stage.Surface, scene: Scene) -> relight.Fit:
    """A Fit with the true specular lobe and normals (an oracle BRDF stage) and the least-squares
    Lambert albedo of what the lobe leaves (the local model that ``fit_subsurface`` must beat)."""
    P = surface.num_samples
    dt = surface.position.dtype
    spec = scene.spec(P, dt)
    y, k = [], []
    for v, cam in enumerate(capture.cameras):
        wi, wo, irr = stage.shading_directions(surface, capture.rig, cam)
        y.append(np.asarray(capture.radiance[v], np.float64)
                 - np.asarray(stage.reflected_radiance_lights(spec, wi, wo, irr), np.float64))
        k.append(np.asarray(stage.reflected_radiance_lights(brdf.Lambert(jnp.ones((P, 3), dt)), wi, wo, irr),
                            np.float64))
    y, k = np.stack(y), np.stack(k)
    m = np.asarray(capture.mask, np.float64)[..., None]
    den = np.sum(m * k * k, axis=(0, 1))
    rho = np.clip(np.sum(m * y * k, axis=(0, 1)) / np.where(den > 0, den, 1.0), 0.0, 1.0)
    f32 = lambda x: jnp.asarray(x, dt)  # noqa: E731
    zeros = jnp.zeros((P,), dt)
    return relight.Fit(rho_d=f32(rho), rho_s=jnp.full((P, 1), F0, dt), alpha=jnp.full((P, 2), ALPHA, dt),
                       normal=surface.normal, tangent=surface.tangent,
                       model=jnp.full((P,), relight.MODELS.index("ggx"), jnp.int32), residual=zeros, heldout=zeros,
                       result=jnp.zeros((P,), jnp.int32), steps=jnp.zeros((P,), jnp.int32),
                       observed=f32(np.asarray(capture.mask).sum((0, 1))), uncertainty=jnp.zeros((P, 9), dt))


def has_per() -> bool:
    """Whether ``relight.fit_subsurface`` takes ``per`` (the per-texel fit)."""
    return "per" in inspect.signature(relight.fit_subsurface).parameters


def verdict(err: np.ndarray, flagged: float) -> str:
    """ok / biased / failed from the per-channel median errors and the flagged fraction (module docstring)."""
    if not np.all(np.isfinite(err)) or flagged > FLAGGED_FAILED:
        return "failed"
    worst = float(np.max(err))
    return "ok" if worst <= ERR_OK else "biased" if worst <= ERR_BIASED else "failed"


def run_cell(scene: Scene, mfp: float, cell: Cell, *, per: str = "region", mfp_range=(0.01, 20.0),
             seed: int = 0) -> dict:
    """Simulate, fit and score one (true mfp, condition) cell; returns the record of the table."""
    t0 = time.perf_counter()
    cap, surf = observe(scene, mfp, cell, seed)
    if cell.brdf == "truth":
        fitted = truth_fit(cap, surf, scene)
    elif cell.brdf == "fit":
        fitted = relight.fit(cap, surf)
    else:
        raise ValueError(f"cell.brdf must be one of {BRDFS}, got {cell.brdf!r}")
    kw = {} if per == "region" else {"per": per}
    g = relight.fit_subsurface(cap, surf, fitted, mfp_range=mfp_range, **kw)
    est = np.asarray(g.mfp, np.float64)
    chosen = np.asarray(g.model) == relight.MODELS.index("subsurface")
    if not np.all(np.isfinite(est[chosen])):
        raise AssertionError(f"non-finite mfp at mfp={mfp} {cell}")
    lo, hi = np.log(mfp_range[0]), np.log(mfp_range[1])
    le = np.log(np.where(est > 0, est, mfp_range[0]))
    pinned = (np.abs(le - lo) < PINNED_LOG) | (np.abs(le - hi) < PINNED_LOG)  # [P, C]
    fitted_mask = chosen[:, None] & ~pinned
    identified = getattr(g, "mfp_identified", None)  # the fitter's own flag, where it has one
    if identified is not None:
        fitted_mask &= np.asarray(identified)
    rel = np.abs(est - mfp) / mfp
    err = np.array([np.median(rel[fitted_mask[:, c], c]) if fitted_mask[:, c].any() else np.nan for c in range(3)])
    err_all = np.median(rel[chosen], axis=0) if chosen.any() else np.full(3, np.nan)
    flagged = float(1.0 - fitted_mask.mean())
    med = np.array([np.median(est[fitted_mask[:, c], c]) if fitted_mask[:, c].any() else np.nan for c in range(3)])
    return dict(mfp=mfp, texel=cell.texel, noise=cell.noise, lights=cell.lights, brdf=cell.brdf,
                footprint=cell.footprint, per=per, texels=surf.num_samples, err=err, err_all=err_all,
                flagged=flagged, chosen=float(chosen.mean()), pinned=float((chosen[:, None] & pinned).mean()),
                median_mfp=med,
                verdict=verdict(err, flagged), seconds=time.perf_counter() - t0)


def sweep(mfps, cells, *, per: str = "region", mfp_range=(0.01, 20.0), sim_texel: float = TEXELS[0], seed: int = 0,
          log=None, scene: Scene | None = None) -> list[dict]:
    """Every (true mfp, cell) pair, each condition simulated once (shared cells computed once).
    Returns one record per distinct (mfp, cell) (see :func:`run_cell`)."""
    if per != "region" and not has_per():
        raise ValueError(f"per={per!r}: this relight.fit_subsurface has no `per` argument (region only)")
    scene = scene or Scene(sim_texel)
    out, seen = [], {}
    for i, mfp in enumerate(mfps):
        for cell in dict.fromkeys(cells):
            if (mfp, cell) in seen:
                continue
            r = run_cell(scene, float(mfp), cell, per=per, mfp_range=mfp_range, seed=seed + 1000 * i)
            seen[(mfp, cell)] = r
            out.append(r)
            if log:
                log(f"  mfp {mfp:6.3f} texel {cell.texel:4.2f} noise {cell.noise:4.0%} lights {cell.lights:3d} "
                    f"brdf {cell.brdf:5s} {cell.footprint:5s}: err {' '.join(f'{e:7.1%}' for e in r['err'])}, "
                    f"flagged {r['flagged']:5.0%}"
                    f" -> {r['verdict']:6s} ({r['seconds']:.1f} s)")
    return out


# --------------------------------------------------------------------------- outputs

_PANELS = (("texel", "texel spacing (mm)", lambda c: f"{c.texel:g}"),
           ("noise", "shot noise", lambda c: f"{c.noise:.0%}"),
           ("lights", "lights (LSX)", lambda c: f"{c.lights}"),
           ("brdf", "BRDF stage", lambda c: {"truth": "true lobe", "fit": "relight.fit"}[c.brdf]),
           ("footprint", f"texel value ({BASE['texel']} mm)", lambda c: c.footprint))


def _find(records, mfp, cell):
    for r in records:
        if (r["mfp"], r["texel"], r["noise"], r["lights"], r["brdf"], r["footprint"]) == (
                mfp, cell.texel, cell.noise, cell.lights, cell.brdf, cell.footprint):
            return r
    return None


def plot(records, mfps, panels, path: Path, title: str, sim_texel: float | None = None):
    """The failure map: one panel per condition, rows = true mfp, colour = worst-channel median error."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    names = [p for p in _PANELS if p[0] in panels]
    widths = [len(panels[p[0]]) for p in names]
    fig, axes = plt.subplots(1, len(names), figsize=(1.2 * sum(widths) + 2.5, 0.42 * len(mfps) + 2.0), squeeze=False,
                             gridspec_kw=dict(width_ratios=widths))
    norm = LogNorm(0.01, 1.0)
    im = None
    for ax, (key, label, fmt) in zip(axes[0], names, strict=True):
        cells = panels[key]
        m = np.full((len(mfps), len(cells)), np.nan)
        for i, mfp in enumerate(mfps):
            for j, c in enumerate(cells):
                r = _find(records, mfp, c)
                if r is None:
                    continue
                e = float(np.max(r["err"])) if np.all(np.isfinite(r["err"])) else np.nan
                m[i, j] = np.clip(e, 0.01, 1.0) if np.isfinite(e) else np.nan
                txt = "n/a" if not np.isfinite(e) else f"{e:.0%}" if e < 10 else ">999%"
                ax.text(j, i + 0.22, f"{txt}\nflag {r['flagged']:.0%}", ha="center", va="center", fontsize=5.5,
                        color="k")
                if r["verdict"] == "failed":
                    ax.plot(j, i - 0.22, "x", color="crimson", ms=7, mew=1.8)
                elif r["verdict"] == "biased":
                    ax.plot(j, i - 0.22, "o", mfc="none", color="darkorange", ms=6, mew=1.5)
        cmap = matplotlib.colormaps["viridis"].copy()
        cmap.set_bad("0.8")
        im = ax.imshow(m, origin="lower", aspect="auto", norm=norm, cmap=cmap)
        # The simulation's own grid: an inverse crime (module docstring), marked on the axis.
        ticks = [fmt(c) + ("\n(sim grid)" if key == "texel" and sim_texel is not None and np.isclose(c.texel, sim_texel)
                           else "") for c in cells]
        ax.set_xticks(range(len(cells)), ticks, fontsize=7)
        ax.set_yticks(range(len(mfps)), [f"{x:.3g}" for x in mfps], fontsize=7)
        ax.set_xlabel(label, fontsize=8)
        if ax is axes[0][0]:
            ax.set_ylabel("true mean free path (mm)", fontsize=8)
    cb = fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85, pad=0.02)
    cb.set_label("worst-channel median |mfp error| / mfp", fontsize=7)
    cb.ax.tick_params(labelsize=6)
    fig.suptitle(title + "\nx = failed, o = biased, no mark = ok; grey = no fitted texel", fontsize=8)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def summary(records, mfps, panels) -> str:
    """Per panel and condition, the true mfps (mm) judged ok / biased / failed (markdown bullets)."""
    lines = []
    for key, label, fmt in _PANELS:
        for c in panels.get(key, []):
            by = {v: [] for v in ("ok", "biased", "failed")}
            for mfp in mfps:
                r = _find(records, mfp, c)
                if r is not None:
                    by[r["verdict"]].append(f"{mfp:.3g}")
            lines.append(f"- {label} = {fmt(c)}: " + "; ".join(f"{v} at {', '.join(m) or '-'}" for v, m in by.items()))
    return "\n".join(lines)


def table(records) -> str:
    lines = ["| mfp (mm) | texel (mm) | footprint | noise | lights | BRDF | texels | err R | err G | err B | "
             "fitted median mfp (R, G, B) | worst err, flags ignored | subsurface chosen | flagged | verdict | s |",
             "|" + "---|" * 16]
    for r in records:
        lines.append(f"| {r['mfp']:.3g} | {r['texel']:g} | {r['footprint']} | {r['noise']:.0%} | {r['lights']} | "
                     f"{r['brdf']} | {r['texels']} | "
                     + " | ".join("n/a" if not np.isfinite(e) else f"{e:.1%}" for e in r["err"])
                     + " | " + ", ".join(f"{x:.3g}" for x in r["median_mfp"])
                     + f" | {np.max(r['err_all']):.1%}"
                     + f" | {r['chosen']:.0%} | {r['flagged']:.0%} | {r['verdict']} | {r['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--per", choices=("region", "texel", "auto"), default="region")
    ap.add_argument("--quick", action="store_true", help="2 mfp x (baseline, coarse texels): a smoke run")
    ap.add_argument("--mfp-range", default="0.01,20", help="fit_subsurface's search bracket (mm)")
    ap.add_argument("--sim-texel", type=float, default=TEXELS[0], help="simulation texel spacing (mm)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help=f"output folder (default {FIG}; --quick: a temporary folder)")
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else Path(tempfile.gettempdir()) / "stability_subsurface_quick" if args.quick \
        else FIG
    out.mkdir(parents=True, exist_ok=True)
    mfp_range = tuple(float(x) for x in args.mfp_range.split(","))
    t_start = time.perf_counter()
    if args.quick:
        mfps = (0.05, 2.0)
        panels = {"texel": [Cell(texel=TEXELS[0]), Cell(texel=TEXELS[-1])]}
    else:
        mfps = MFPS
        panels = sweep_cells()
    cells = [c for cs in panels.values() for c in cs]
    print(f"# machine: {machine()}")
    print(f"# per={args.per}, true mfp {[round(x, 3) for x in mfps]} mm, {len(dict.fromkeys(cells))} conditions, "
          f"search bracket {mfp_range} mm, simulation texel {args.sim_texel} mm")
    records = sweep(mfps, cells, per=args.per, mfp_range=mfp_range, sim_texel=args.sim_texel, seed=args.seed,
                    log=lambda s: print(s, flush=True))
    total = time.perf_counter() - t_start
    tab = table(records)
    print(tab)
    stem = "stability_subsurface"
    title = (f"relight.fit_subsurface(per={args.per!r}): {STRIP_MM[0]:g} x {STRIP_MM[1]:g} mm skin strip between "
             f"{WALL_MM:g} mm walls, Light Stage X, search bracket {mfp_range} mm\nbaseline: texel {BASE['texel']} mm "
             f"(point samples of a {args.sim_texel} mm simulation), shot noise {BASE['noise']:.0%}, "
             f"{BASE['lights']} lights, true specular lobe; each panel varies one of them")
    plot(records, mfps, panels, out / f"{stem}.png", title, sim_texel=args.sim_texel)
    cmd = "python scripts/stability_subsurface.py " + " ".join(sys.argv[1:] if argv is None else argv)
    setup = __doc__[__doc__.index("Scene:"):__doc__.index("Writes docs")].strip()
    (out / f"{stem}.md").write_text(
        f"# Stability of relight.fit_subsurface: where the mean-free-path fit fails\n\n"
        f"Machine: {machine()}\n\n`{cmd.strip()}` ({total:.0f} s wall)\n\n![failure map]({stem}.png)\n\n"
        f"{setup}\n\n"
        f"per={args.per}; search bracket {mfp_range} mm; simulation texel {args.sim_texel} mm; thresholds: ok <= "
        f"{ERR_OK:.0%} worst-channel median error and <= {FLAGGED_FAILED:.0%} flagged, biased <= {ERR_BIASED:.0%}, "
        f"else failed.\n\nVerdicts by condition (true mfp in mm):\n\n{summary(records, mfps, panels)}\n\n{tab}\n")
    print(f"wrote {out / stem}.png and .md; total {total:.0f} s")
    return records


if __name__ == "__main__":
    main()
