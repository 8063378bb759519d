"""``relight export MAPS_DIR --gltf OUT.glb``: a fitted map set as one binary glTF 2.0 file
(``relight.export.write_gltf``): the mesh with its UVs (metres), the maps as a PBR material with
KHR_materials_specular (and KHR_materials_anisotropy where a texel is anisotropic), what glTF cannot express
in extras. The mapping and its measured approximations: docs/export.md."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, add_mesh_flags, finish_parser, mesh_from_args, summary


def add_parser(sub) -> None:
    p = sub.add_parser("export", help="export a fitted map set as a binary glTF 2.0 file (.glb)",
                       description="Write a fitted map set (the folder `relight fit --out` writes, or a demo's "
                                   "maps/) as one binary glTF 2.0 file: the set's mesh with its UVs, in metres; a "
                                   "metallic-roughness material whose base colour, roughness, normal, "
                                   "KHR_materials_specular (F0) and KHR_materials_anisotropy textures are PNGs at "
                                   "the set's resolution; each texel's rung, the mean free path, the coverage, the "
                                   "units and the rig in the root's extras.relight. Blinn-Phong texels become GGX "
                                   "of the same alpha, subsurface texels a local Lambert term (docs/export.md "
                                   "has the mapping and the measured differences).")
    p.add_argument("maps", metavar="MAPS_DIR", help="a map set (maps.json + the EXR maps)")
    p.add_argument("--gltf", required=True, metavar="OUT.glb", help="the binary glTF file to write")
    add_mesh_flags(p, "the set's mesh, if it moved since the fit (.obj/.ply/.glb with the same UVs); default: "
                      "the one maps.json records")
    p.add_argument("--coverage-alpha", action="store_true",
                   help="cut out the texels no camera saw (base colour alpha = coverage, alphaMode MASK); default: "
                        "they keep the map set's fill (the nearest seen texel's material) and the coverage is in "
                        "extras only")
    p.add_argument("--f0-max", type=float, default=None, metavar="F0",
                   help="the F0 the 8-bit specular colour texture spans; a higher fitted F0 is clamped to it and "
                        "counted (default: the largest fitted F0, nothing clamped; e.g. 0.1 gives skin's F0 ~ 0.03 "
                        "finer steps when a few outlier texels reach 1)")
    finish_parser(p, run)


def run(args) -> int:
    import sys

    from ..export import write_gltf
    from ..io import is_map_set

    folder, out = Path(args.maps), Path(args.gltf)
    if not folder.is_dir():
        raise CLIError(f"{folder}: no such map-set folder")
    if not is_map_set(folder):
        hint = f" (its maps/ is one: relight export {folder / 'maps'})" if is_map_set(folder / "maps") else ""
        raise CLIError(f"{folder}: not a map set (no maps.json of format relight-maps){hint}")
    if out.suffix.lower() != ".glb":
        raise CLIError(f"--gltf {out}: must end in .glb (binary glTF)")
    if out.is_dir():
        raise CLIError(f"--gltf {out}: a folder; name the .glb file to write")
    if args.mesh is None and (args.units is not None or args.scale is not None or args.center is not None):
        raise CLIError("--units / --scale / --center place a --mesh; give the mesh too")
    mesh = mesh_from_args(args) if args.mesh is not None else None
    if args.f0_max is not None and not 0.0 < args.f0_max <= 1.0:
        raise CLIError(f"--f0-max {args.f0_max}: must be in (0, 1]")
    r = write_gltf(folder, out, mesh=mesh, coverage_alpha=args.coverage_alpha, f0_max=args.f0_max)
    if summary(args):
        rungs = ", ".join(f"{name} {n}" for name, n in r.rungs.items() if n)
        print(f"wrote {out} ({r.bytes / 1e6:.2f} MB: {r.vertices} vertices, {r.faces} triangles, "
              f"{r.resolution[0]}x{r.resolution[1]} textures; texels: {rungs}; {', '.join(r.extensions)})")
        if r.clamped.get("base_color"):
            print(f"relight export: note: {r.clamped['base_color']} texel(s) have a base colour rho_d / (1 - F0) "
                  "above 1, clamped (glTF's base colour is at most 1)", file=sys.stderr)
        if r.clamped.get("f0"):
            print(f"relight export: note: {r.clamped['f0']} texel(s) have a fitted F0 above --f0-max "
                  f"{args.f0_max:g}, clamped to it", file=sys.stderr)
        if r.clamped.get("normal"):
            print(f"relight export: note: {r.clamped['normal']} texel(s) have a fitted normal beyond the mesh's "
                  "horizon, held at its edge", file=sys.stderr)
        if r.filled:
            print(f"relight export: {r.filled} texel(s) no camera saw carry the map set's fill"
                  f"{' and are cut out (alpha 0)' if args.coverage_alpha else ' (--coverage-alpha cuts them out)'}",
                  file=sys.stderr)
    return 0
