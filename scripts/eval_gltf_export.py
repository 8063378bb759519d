"""Measure what the glTF export approximates (docs/export.md): each rung of a fitted map set rendered by
relight's own renderer as fitted, and as read back from the .glb.

For each rung of the ladder, every texel of the map set is given that rung (its fitted parameters kept), the
maps are exported with ``relight.export.write_gltf`` and read back with ``relight.export.gltf_maps`` (what a
glTF renderer draws, in relight's model: after the 8-bit quantisation and the rung conversions), and both are
rendered with ``relight.render.render_view`` (the rig method, the map set's first camera, the bundled
environment). The table gives the relative RMS of the two images over the pixels both render, per rung, and
for the map set as fitted (its own mix of rungs).

A second column measures the one term in which glTF's BRDF (its specification's Appendix B with
KHR_materials_specular) differs from relight's for the same parameters: glTF weights the diffuse term by
1 - F(V.H), which the export's base colour rho_d / (1 - F0) undoes only at normal incidence. Evaluated at the
texels the camera sees, under the environment sampled in 4096 Fibonacci directions (no shadows): relative RMS
of sum f cos L between the glTF weighting and relight's.

Usage:
    python scripts/eval_gltf_export.py --maps OUT/maps [--size 128] [--md docs/figures/gltf_export.md]

docs/figures/gltf_export.md holds the run on ``relight demo --resolution 64 --cameras 3 --image-size 96``'s
maps (its "Map set" line edited from the temporary path to that command).

Without ``--maps`` a ``relight demo`` (resolution 48, 2 cameras) is run first into a temporary folder.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from _common import FIG, parser


def _demo_maps(folder: Path) -> Path:
    from relight.demo import run_demo

    print("running relight demo (resolution 48, 2 cameras, 96 px) for a fitted map set ...")
    run_demo(resolution=48, cameras=2, image_size=96).write(folder)
    return folder / "maps"


def _rel_rms(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """Relative RMS of b against a over the pixels where both are non-zero, and their count."""
    mask = (a.sum(-1) > 0) & (b.sum(-1) > 0)
    d = (a - b)[mask]
    return float(np.sqrt(np.mean(d**2)) / np.sqrt(np.mean(a[mask] ** 2))), int(mask.sum())


def _fresnel_weight_rms(maps, surface, camera, env) -> float:
    """Relative RMS (over the texels facing the camera) of sum_d f cos L with glTF's diffuse weighting
    (1 - F(V.H)) / (1 - F0) against relight's (1), for the same parameters."""
    import jax
    import jax.numpy as jnp

    import brdf
    from relight.envmap import sample_latlong
    from relight.materials import LAMBERT

    dirs = brdf.fibonacci_sphere(4096)
    radiance = np.asarray(sample_latlong(env.radiance, jnp.asarray(dirs)), np.float64) * (4 * np.pi / len(dirs))
    pos = np.asarray(surface.position, np.float64)
    center = -np.asarray(camera.R, np.float64).T @ np.asarray(camera.t, np.float64)
    wo = center - pos
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    framed = maps.frame(surface)
    wo_l = np.asarray(framed.to_local(jnp.asarray(wo)), np.float64)
    facing = wo_l[:, 2] > 0.05
    wi_l = np.asarray(framed.to_local(jnp.broadcast_to(jnp.asarray(dirs)[:, None, :], (len(dirs),) + pos.shape)),
                      np.float64)  # [D, P, 3]
    ladder = jax.tree_util.tree_map(lambda x: x[None], maps.brdf(include_diffuse=True))  # parameters [1, P, C]
    f = np.asarray(ladder(jnp.asarray(wi_l), jnp.asarray(wo_l)[None]), np.float64)
    cos = np.clip(wi_l[..., 2:3], 0.0, None) * (wo_l[None, :, 2:3] > 0)
    lambert = np.asarray(maps.model) == LAMBERT  # specular 0 in the file: F0 = F90 = 0, no weighting
    f0 = np.where(lambert, 0.0, np.asarray(maps.rho_s, np.float64)[:, 0])
    h = wi_l + wo_l[None]
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)
    F = np.where(lambert, 0.0, f0 + (1.0 - f0) * (1.0 - np.clip(np.sum(h * wo_l[None], -1), 0.0, 1.0)) ** 5)
    weight = ((1.0 - F) / (1.0 - np.minimum(f0, 0.999)))[..., None]
    diffuse = np.asarray(maps.rho_d, np.float64)[None] / np.pi
    L_rel = np.sum(f * cos * radiance[:, None, :], axis=0)
    L_gltf = L_rel + np.sum(diffuse * (weight - 1.0) * cos * radiance[:, None, :], axis=0)
    d = (L_gltf - L_rel)[facing]
    return float(np.sqrt(np.mean(d**2)) / np.sqrt(np.mean(L_rel[facing] ** 2)))


def main() -> None:
    p = parser(__doc__)
    p.add_argument("--maps", default=None, help="a fitted map set (default: run a small relight demo first)")
    p.add_argument("--size", type=int, default=128, help="pixels on the camera's longer side (default: 128)")
    p.add_argument("--f0-max", type=float, default=0.1, help="f0_max of the extra ggx case (default: 0.1)")
    p.add_argument("--md", default=str(FIG / "gltf_export.md"), help="the markdown table to write")
    args = p.parse_args()

    import stage
    from relight import material_maps
    from relight.envmap import bundled_envmap_path, load_envmap
    from relight.export import gltf_maps, write_gltf
    from relight.io import load_texel_maps
    from relight.materials import MODELS
    from relight.render import render_view, scaled_camera

    tmp = Path(tempfile.mkdtemp(prefix="relight-gltf-"))
    folder = Path(args.maps) if args.maps else _demo_maps(tmp / "demo")
    tm = load_texel_maps(folder)
    camera = scaled_camera(tm.cameras[0] if tm.cameras else stage.front_camera(tm.mesh, args.size), args.size)
    env = load_envmap(bundled_envmap_path())
    fitted = tm.maps
    fields = {k: np.asarray(getattr(fitted, k)) for k in ("rho_d", "rho_s", "alpha", "normal", "tangent", "mfp")}
    P = tm.surface.num_samples
    rows = []
    cases = [(name, np.full(P, r, np.int32), None) for r, name in enumerate(MODELS)]
    cases.append((f"ggx, f0_max {args.f0_max:g}", np.full(P, MODELS.index("ggx"), np.int32), args.f0_max))
    cases.append(("as fitted", np.asarray(fitted.model), None))
    for name, model, f0_max in cases:
        t0 = time.perf_counter()
        maps = material_maps(tm.surface, fields["rho_d"], fields["rho_s"], fields["alpha"], normal=fields["normal"],
                             tangent=fields["tangent"], mfp=fields["mfp"], model=model)
        glb = tmp / "case.glb"
        export = write_gltf(maps, glb, mesh=tm.mesh, surface=tm.surface, f0_max=f0_max)
        back = gltf_maps(glb, tm.surface)
        a = render_view(maps, tm.surface, tm.mesh, camera, env, background=False)
        b = render_view(back, tm.surface, tm.mesh, camera, env, background=False)
        rms, pixels = _rel_rms(a, b)
        weight = _fresnel_weight_rms(back, tm.surface, camera, env)
        rows.append((name, rms, weight, pixels, export.clamped["base_color"], export.clamped["f0"]))
        print(f"{name:12s} render rel. RMS {100 * rms:6.2f}% over {pixels} px; glTF diffuse weighting "
              f"{100 * weight:5.2f}%; base colour / F0 clamped on {export.clamped['base_color']} / "
              f"{export.clamped['f0']} texel(s) "
              f"({time.perf_counter() - t0:.1f} s)")

    lines = ["# The glTF export against the fitted maps (scripts/eval_gltf_export.py)", "",
             f"Map set: {folder} ({P} texels, {tm.textures.resolution[0]}x{tm.textures.resolution[1]}), camera "
             f"{camera.width}x{camera.height} px, the bundled environment, `render_view` (rig method).", "",
             "| rung (every texel) | render rel. RMS, fitted vs read back | glTF's diffuse weighting | pixels | "
             "texels clamped: base colour / F0 |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {n} | {100 * r:.2f}% | {100 * w:.2f}% | {px} | {c} / {f} |" for n, r, w, px, c, f in rows]
    Path(args.md).write_text("\n".join(lines) + "\n")
    print(f"wrote {args.md}")


if __name__ == "__main__":
    main()
