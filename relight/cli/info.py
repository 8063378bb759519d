"""``relight info``: versions, devices, bundled data and the shared data folder; ``relight info PHOTOS_DIR``:
a photo capture summarised, with warnings for likely mistakes, before any fitting
(``relight.io.check_photo_capture``)."""

from __future__ import annotations

from pathlib import Path

from ._flags import add_mesh_flags, add_rig_file_flags
from ._guard import guarded


def add_parser(sub) -> None:
    i = sub.add_parser("info", help="versions, devices, bundled data and the shared data folder",
                       description="Versions, devices, bundled data and the shared data folder; with a photo "
                                   "capture folder (docs/capture_layout.md), its cameras, lights, image sizes, "
                                   "saturated and dark fractions, radiance range and lights lit per camera, "
                                   "with warnings for likely mistakes, before any fitting.")
    i.add_argument("photos", nargs="?", help="a photo capture folder (capture.json, format relight-photos)")
    add_mesh_flags(i, "the subject's mesh ('head' for the bundled one), placed as for relight fit: lights "
                      "inside its bounds are reported (default: none)")
    i.add_argument("--stride", type=int, default=4, help="sample every Nth row and column of each mask (default 4)")
    add_rig_file_flags(i)
    i.set_defaults(func=guarded(run))


def _photos(args) -> int:
    from ..io import check_photo_capture, read_photo_capture, spec_mesh
    from ._flags import at_least, mesh_from_args

    at_least("--stride", args.stride, 1)
    cap = read_photo_capture(args.photos, rig_units=args.rig_units, rig_up=args.rig_up)
    mesh = None if args.mesh is None else spec_mesh(mesh_from_args(args), "--mesh")
    check = check_photo_capture(cap, stride=args.stride, mesh=mesh)
    r = check.rig
    print(f"{cap.folder}: {cap.n_views} cameras, {r['lights']} lights ({'near' if r['near_field'] else 'distant'}"
          f" field, {r['radius_mm'][0]:.4g}-{r['radius_mm'][1]:.4g} mm from the centre)")
    print(f"pixels: {check.pixels}")
    for v in check.views:
        sat, dark = v["saturated_fraction"], v["dark_fraction"]
        print(f"  {v['camera']}: {v['size'][0]}x{v['size'][1]} {v['format']}"
              f"{'' if v['scale_stated'] else ' (no exposure/gain)'}, saturated median {100 * sat['median']:.1f}% "
              f"max {100 * sat['max']:.1f}%, dark median {100 * dark['median']:.1f}%, radiance "
              f"{v['radiance_range'][0]:.3g}-{v['radiance_range'][1]:.3g}, lights lit {v['lights_lit']}")
    for w in check.warnings:
        print(f"warning: {w}")
    if not check.warnings:
        print("no warnings")
    return 0


def _version(dist: str) -> str:
    try:
        from importlib.metadata import version

        return version(dist)
    except Exception:
        return "not installed"


def run(args) -> int:
    if getattr(args, "photos", None):
        return _photos(args)
    import platform

    import jax

    import stage

    from ..envmap import bundled_envmap_path

    print(f"relight {_version('lightstage-relight')} (python {platform.python_version()})")
    print("libraries: " + ", ".join(f"{d} {_version(d)}" for d in ("jax", "equinox", "optimistix", "numpy", "OpenEXR",
                                                                    "trimesh", "embreex")))
    devices = jax.devices()
    print(f"jax {jax.__version__} on {jax.default_backend()} ({len(devices)} device(s): "
          f"{', '.join(str(d) for d in devices[:4])}{', ...' if len(devices) > 4 else ''})")
    rig = stage.light_stage_x()
    print(f"bundled rig: ICT Light Stage X, {rig.num_lights} lights")
    print(f"bundled mesh: {stage.head_mesh_path()}")
    print(f"bundled environment map: {bundled_envmap_path()}")
    shared = Path(__file__).resolve().parents[2] / "shared" / "data"
    if shared.is_dir():
        entries = sorted(p.name for p in shared.iterdir())
        print(f"shared data: {shared} ({', '.join(entries[:8])}{', ...' if len(entries) > 8 else ''})")
    else:
        print("shared data: none (../shared/data not found)")
    return 0
