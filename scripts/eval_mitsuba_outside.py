"""Which rung for a material the ladder does not hold: the Mitsuba head of scripts/eval_mitsuba_photos.py
rendered twice, once with the ladder's own material and once with Mitsuba's ``roughplastic``, each fitted by
every rung and by ``model="auto"`` on three quarters of the lights and scored on the held-out quarter.

    python scripts/eval_mitsuba_outside.py [--work DIR] [--out docs/figures] [--size 256] [--lights 48]
                                           [--cameras 3] [--spp 16] [--resolution 128]

The captures (eval_mitsuba_photos.render_capture: 16-bit PNG counts, OpenCV cameras.json, near-field point
lights at the Light Stage X's positions, masks from a coverage render) are:

* ``ladder``: write_mitsuba_scene's material (rho_d = the skin albedo texture + a GGX lobe of F0 0.04 and
  alpha 0.35 with Schlick's Fresnel): the ladder's GGX rung is the exact model;
* ``roughplastic``: Mitsuba's ``roughplastic`` (GGX, alpha 0.35, interior IOR 1.5, so F0 = 0.04 at normal
  incidence; the same albedo texture as ``diffuse_reflectance``). Not in the ladder: its diffuse term is the
  light refracted into a dielectric layer and back out, attenuated by both Fresnel transmissions and
  renormalised for internal reflection, and its specular lobe has the full dielectric Fresnel. The right
  answer is the closest rung.

Each capture is read through the photo path (``read_photo_capture`` -> ``photos_to_texels``, 128^2 texels);
every fourth light (12 of 48) is held out; each fit (``relight.fit`` with the library's defaults otherwise) is
on the other 36. Score: the relative RMS of the fit's prediction of the held-out lights
(``relight.evaluation.predict_fit``, every camera) against the photographs, over the valid held-out observations
(seen, lit, unclipped) of the texels seen by >= 1 camera that no fit flagged failed:
sqrt(sum (pred - obs)^2 / sum obs^2) over (camera, light, texel, channel). The render is cached in ``--work``
(default: a folder under the system's temporary directory) and reused while its settings hold. Writes
mitsuba_outside.json / .md into ``--out``.
"""

from __future__ import annotations

import json
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import eval_mitsuba_photos as emp
import numpy as np
from _common import FIG, machine, parser

MATERIALS = ("ladder", "roughplastic")
# roughplastic's interior index of refraction: F0 = ((1.5 - 1) / (1.5 + 1))^2 = 0.04, the ladder capture's F0.
INT_IOR = 1.5
HOLDOUT = 4
RUNGS = ("lambert", "blinn_phong", "ggx", "ggx_aniso", "auto")


def roughplastic(xml: Path) -> None:
    """Rewrite an OLAT scene (eval_mitsuba_photos._edit_scene's) in place: the shape's BSDF becomes Mitsuba's
    ``roughplastic`` (GGX, alpha ALPHA, int_ior INT_IOR) whose diffuse reflectance is the scene's rho_d texture
    (write_mitsuba_scene's ``diffuse_blend.exr`` is rho_d / (1 - 0.99); written back scaled as ``albedo.exr``)."""
    from relight.io import read_exr, write_exr

    tex = xml.parent / "mitsuba"
    write_exr(tex / "albedo.exr", (0.01 * read_exr(tex / "diffuse_blend.exr")).astype(np.float32))
    tree = ET.parse(xml)
    shape = tree.getroot().find("shape")
    for b in shape.findall("bsdf"):
        shape.remove(b)
    b = ET.SubElement(shape, "bsdf", {"type": "roughplastic"})
    ET.SubElement(b, "string", {"name": "distribution", "value": "ggx"})
    ET.SubElement(b, "float", {"name": "alpha", "value": str(emp.ALPHA)})
    ET.SubElement(b, "float", {"name": "int_ior", "value": str(INT_IOR)})
    t = ET.SubElement(b, "texture", {"type": "bitmap", "name": "diffuse_reflectance"})
    ET.SubElement(t, "string", {"name": "filename", "value": "mitsuba/albedo.exr"})
    ET.SubElement(t, "boolean", {"name": "raw", "value": "true"})
    tree.write(xml, encoding="utf-8", xml_declaration=True)


def render(work: Path, material: str, size: int, lights: int, cameras: int, spp: int, resolution: int,
           progress=print) -> Path:
    """The capture folder of ``material`` under ``work`` (rendered unless its capture.json exists)."""
    import stage

    folder = work / material / "photos"
    stamp = work / material / "settings.json"
    settings = json.dumps({"size": size, "lights": lights, "cameras": cameras, "spp": spp, "resolution": resolution,
                           "alpha": emp.ALPHA, "f0": emp.F0, "int_ior": INT_IOR})
    if (folder / "capture.json").is_file() and stamp.is_file() and stamp.read_text() == settings:
        progress(f"{material}: the render in {folder}")
        return folder
    if folder.exists():  # an interrupted render, or another setting's
        import shutil

        shutil.rmtree(folder)
    (work / material).mkdir(parents=True, exist_ok=True)
    stamp.unlink(missing_ok=True)
    mesh = stage.load_head()
    rig = stage.light_stage_x().subset(emp.pick_lights(lights))
    cams = emp.capture_cameras(mesh, cameras, size)
    names = [f"cam{i:03d}" for i in range(cameras)]
    surface, maps = emp.truth_maps(mesh, resolution)
    progress(f"{material}: rendering {cameras} cameras x {lights} lights at {size} x {size} px, {spp} spp")
    emp.render_capture(folder, mesh, surface, maps, rig, cams, names, spp, work / material,
                       progress, material=roughplastic if material == "roughplastic" else None)
    stamp.write_text(settings)
    return folder


def score(folder: Path, resolution: int, progress=print) -> dict:
    """Every rung and ``auto`` fitted on the training lights of the capture in ``folder``, scored on the
    held-out lights (module docstring)."""
    import relight
    import stage
    from relight.evaluation import predict_fit, relative_rms
    from relight.io import photos_to_texels, read_photo_capture

    mesh = stage.load_head()
    capture, surface, report = photos_to_texels(read_photo_capture(folder), mesh, resolution)
    seen = ~np.asarray(report.unseen, bool)
    L = capture.rig.num_lights
    held = np.arange(L) % HOLDOUT == HOLDOUT // 2
    train, test = capture.lights(np.nonzero(~held)[0]), capture.lights(np.nonzero(held)[0])
    obs = np.asarray(test.radiance, np.float64)  # [V, L', P, 3]
    fits, preds, seconds = {}, {}, {}
    for model in RUNGS:
        t0 = time.perf_counter()
        fits[model] = relight.fit(train, surface, model=model)
        seconds[model] = round(time.perf_counter() - t0, 1)
        preds[model] = np.stack([predict_fit(fits[model], test, surface, view=v) for v in range(obs.shape[0])])
    # Scored where every fit has the texel (a texel with too few valid training observations gets the fit's
    # grey defaults and is flagged failed): the same observations for every model.
    fitted = seen & ~np.logical_or.reduce([np.asarray(f.failed, bool) for f in fits.values()])
    valid = np.asarray(test.mask, bool) & fitted[None, None]
    flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731  [V, L', ...] -> [V L', ...]
    rows = []
    for model, f in fits.items():
        err = relative_rms(flat(preds[model]), flat(obs), flat(valid))
        rung = np.asarray(f.model)[fitted]
        rows.append({"model": model, "heldout": err, "seconds": seconds[model],
                     "collapsed": float(np.mean(np.asarray(f.collapsed, bool)[fitted])),
                     "rungs": {m: float(np.mean(rung == i)) for i, m in enumerate(relight.MODELS)
                               if np.any(rung == i)}})
        progress(f"  {model:12s} held-out relative RMS {err:.4f} ({seconds[model]:.0f} s)")
    return {"texels_seen": int(seen.sum()), "texels_fitted": int(fitted.sum()), "heldout_lights": int(held.sum()),
            "training_lights": int((~held).sum()), "heldout_observations": int(valid.sum()), "fits": rows}


def markdown(result: dict) -> str:
    s = result["settings"]
    lines = ["# Which rung for a material the ladder does not hold", "",
             f"`{result['command']}` ({result['total_s']:.0f} s on {result['machine']}).", "",
             f"The bundled head rendered by Mitsuba 3 (scalar_rgb, {s['spp']} spp, direct light with shadows) from "
             f"{s['cameras']} cameras ({s['size']} x {s['size']} px) under {s['lights']} Light Stage X lights, as "
             "16-bit PNG photographs, read through the photo path onto "
             f"{s['resolution']}^2 texels. *ladder*: the ladder's own material (Lambert + GGX, Schlick Fresnel); "
             "*roughplastic*: Mitsuba's `roughplastic` (GGX alpha 0.35, IOR 1.5), which no rung holds. Each fit "
             f"on {HOLDOUT - 1} of every {HOLDOUT} lights; held-out relative RMS of its prediction of the other "
             "lights against the photographs, over the valid held-out observations (camera, light, texel) of "
             "the texels seen by >= 1 camera and fitted by every model (none flagged failed), and RGB. "
             "Bold: the best fixed rung.", ""]
    head = "| model | " + " | ".join(f"{m}: held out" for m in MATERIALS) + " | " + \
        " | ".join(f"{m}: rungs `auto` chose" for m in MATERIALS) + " |"
    lines += [head, "|" + " --- |" * (1 + 2 * len(MATERIALS))]
    best = {m: min(r["heldout"] for r in result[m]["fits"] if r["model"] != "auto") for m in MATERIALS}
    for i, model in enumerate(RUNGS):
        cells = []
        for m in MATERIALS:
            r = result[m]["fits"][i]
            v = f"{r['heldout']:.4f}"
            cells.append(f"**{v}**" if model != "auto" and r["heldout"] == best[m] else
                         (f"{v} ({r['heldout'] / best[m]:.3f}x the best)" if model == "auto" else v))
        picks = []
        for m in MATERIALS:
            r = result[m]["fits"][i]
            picks.append(", ".join(f"{k} {100 * v:.1f}%" for k, v in r["rungs"].items()) if model == "auto" else "")
        lines.append(f"| {model} | " + " | ".join(cells) + " | " + " | ".join(picks) + " |")
    lines += ["", "Observations: " + "; ".join(
        f"{m} {result[m]['heldout_observations']} held out over the {result[m]['texels_fitted']} texels every "
        f"fit fitted (of {result[m]['texels_seen']} seen) "
        f"({result[m]['heldout_lights']} held-out, {result[m]['training_lights']} training lights)"
        for m in MATERIALS) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = parser(__doc__)
    p.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "relight-eval-mitsuba-outside",
                   help="render cache (reused when present)")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--lights", type=int, default=48)
    p.add_argument("--cameras", type=int, default=3)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--out", type=Path, default=FIG)
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    result = {"settings": {k: getattr(a, k) for k in ("size", "lights", "cameras", "spp", "resolution")}}
    for m in MATERIALS:
        folder = render(a.work, m, a.size, a.lights, a.cameras, a.spp, a.resolution)
        print(f"{m}: fitting")
        result[m] = score(folder, a.resolution)
    result["total_s"] = round(time.perf_counter() - t0, 1)
    result["machine"] = machine()
    result["command"] = "python scripts/eval_mitsuba_outside.py" + "".join(
        f" --{k} {v}" for k, v in result["settings"].items())
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "mitsuba_outside.json").write_text(json.dumps(result, indent=1) + "\n")
    md = markdown(result)
    (a.out / "mitsuba_outside.md").write_text(md)
    print(md)
    print(f"wrote {a.out / 'mitsuba_outside.json'} and .md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
