"""relight.export.write_gltf / relight export: the GLB container, trimesh reading it back, the tangents, the
texture mapping of every rung (base colour, roughness, F0, anisotropy, normals), the fill of unseen texels,
and the Khronos glTF Validator on a demo's maps (skipped, with the reason, where node or the gltf-validator
package is absent)."""

import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

import stage
import tests.scenes as scenes
from relight.export import gltf_maps, read_gltf, write_gltf
from relight.image import srgb_decode, srgb_encode
from relight.materials import BLINN_PHONG, GGX, GGX_ANISO, LAMBERT, SUBSURFACE, material_maps

RES = 16
TILT_DEG = 20.0
# One 8-bit code of a texture channel, and the angle one code of a normal-map channel can move a normal
# (2 / 255 of a unit vector's component ~ 0.45 degrees; half of it from rounding, then the three channels').
CODE = 1.0 / 255.0
NORMAL_DEG = 0.5


def _quad(mirror: bool = False, uv_scale: float = 1.0):
    """A 100 mm square facing +y (tests.scenes.plane: u along +x, v along -z), its UVs mirrored in u and/or
    scaled toward the corner (0, 0) (then only part of the texel grid is on the mesh)."""
    mesh = scenes.plane(size=100.0, n=2)
    uv = np.asarray(mesh.uv, np.float64)
    if mirror:
        uv[:, 0] = 1.0 - uv[:, 0]
    return stage.Mesh(mesh.vertices, mesh.faces, mesh.normals, uv * uv_scale, "quad")


def _maps(surface, tilt_axis="tangent"):
    """Maps with every rung (by texel row), varied albedos and alphas, and the normal tilted TILT_DEG from the
    mesh's toward the surface's tangent (+x) or bitangent."""
    P = surface.num_samples
    rng = np.random.default_rng(3)
    n0 = np.asarray(surface.normal, np.float64)
    axis = np.asarray(surface.tangent if tilt_axis == "tangent" else surface.bitangent, np.float64)
    th = np.radians(TILT_DEG)
    normal = np.cos(th) * n0 + np.sin(th) * axis
    tangent = np.cross(np.asarray(surface.bitangent, np.float64), normal)  # in the tilted plane, along +u
    row = np.asarray(surface.texel_index) // RES
    model = np.array([LAMBERT, BLINN_PHONG, GGX, GGX_ANISO, SUBSURFACE])[row % 5]
    alpha = rng.uniform(0.1, 0.6, (P, 2))
    alpha[:, 1] = np.where(model >= GGX_ANISO, alpha[:, 1], alpha[:, 0])
    return material_maps(surface, rng.uniform(0.05, 0.8, (P, 3)), rng.uniform(0.02, 0.06, P), alpha,
                         normal=normal, tangent=tangent, mfp=rng.uniform(0.5, 3.0, (P, 3)), model=model)


@pytest.fixture(scope="module")
def quad(tmp_path_factory):
    """(path, mesh, surface, maps, export) of the quad's export."""
    mesh = _quad()
    surface = stage.texel_samples(mesh, RES)
    maps = _maps(surface)
    path = tmp_path_factory.mktemp("gltf") / "quad.glb"
    return path, mesh, surface, maps, write_gltf(maps, path, mesh=mesh, surface=surface)


def _validator():
    """The Khronos glTF Validator's entry point (npm package gltf-validator, global), or skip with the reason."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node / npm not installed (the Khronos glTF Validator runs on node; .ci/run installs it)")
    root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True, timeout=60).stdout.strip()
    package = Path(root) / "gltf-validator"
    if not (package / "package.json").is_file():
        pytest.skip(f"the npm package gltf-validator is not installed under {root} (npm install -g gltf-validator)")
    return node, package


def _validate(path: Path) -> dict:
    node, package = _validator()
    script = ("const fs = require('fs'); const v = require(process.argv[1]);"
              "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), {maxIssues: 0})"
              ".then(r => console.log(JSON.stringify(r.issues)), e => { console.error(String(e)); process.exit(3); });")
    out = subprocess.run([node, "-e", script, str(package), str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_glb_container(quad):
    """Magic, version, length, the JSON then BIN chunk with 4-byte lengths, aligned views, POSITION's bounds."""
    path, mesh, *_ = quad
    data = path.read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data)
    assert (magic, version, total) == (b"glTF", 2, len(data))
    json_len, json_kind = struct.unpack_from("<I4s", data, 12)
    bin_len, bin_kind = struct.unpack_from("<I4s", data, 20 + json_len)
    assert (json_kind, bin_kind) == (b"JSON", b"BIN\0")
    assert json_len % 4 == 0 and bin_len % 4 == 0 and 28 + json_len + bin_len == len(data)
    doc = json.loads(data[20:20 + json_len])
    assert doc["buffers"] == [{"byteLength": bin_len}]
    assert all(v["byteOffset"] % 4 == 0 and v["byteOffset"] + v["byteLength"] <= bin_len for v in doc["bufferViews"])
    prim = doc["meshes"][0]["primitives"][0]
    assert {doc["bufferViews"][doc["accessors"][a]["bufferView"]]["target"] for a in prim["attributes"].values()} \
        == {34962}
    assert doc["bufferViews"][doc["accessors"][prim["indices"]]["bufferView"]]["target"] == 34963
    pos = doc["accessors"][prim["attributes"]["POSITION"]]
    v_m = np.asarray(mesh.vertices, np.float32) * np.float32(1e-3)
    np.testing.assert_allclose(pos["min"], v_m.min(0), rtol=1e-6)
    np.testing.assert_allclose(pos["max"], v_m.max(0), rtol=1e-6)
    assert "KHR_materials_specular" in doc["extensionsUsed"] and "KHR_materials_anisotropy" in doc["extensionsUsed"]
    rel = doc["extras"]["relight"]
    assert rel["units"]["length"] == "m" and rel["rungs"] == {"lambert": 64, "blinn_phong": 48, "ggx": 48,
                                                              "ggx_aniso": 48, "subsurface": 48}


def test_trimesh_reads_back_the_mesh_and_maps(quad):
    """trimesh gets the same vertices (in metres), triangles and UVs, the base colour rho_d / (1 - F0) in sRGB and
    the roughness sqrt(alpha), each within one 8-bit code."""
    import trimesh

    path, mesh, surface, maps, _ = quad
    geom = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(geom.vertices * 1e3, mesh.vertices, atol=1e-4)
    np.testing.assert_array_equal(geom.faces, mesh.faces)
    np.testing.assert_allclose(geom.visual.uv, mesh.uv, atol=1e-7)
    mat = geom.visual.material
    at = np.asarray(surface.texel_index)
    base = np.asarray(mat.baseColorTexture.convert("RGB")).reshape(-1, 3)[at] / 255.0
    model = np.asarray(maps.model)
    f0 = np.where(model == LAMBERT, 0.0, np.asarray(maps.rho_s)[:, 0])
    want = np.asarray(srgb_encode(np.asarray(maps.rho_d, np.float64) / (1.0 - f0)[:, None]))
    # one code of the stored base colour, plus the F0 it is divided by (itself quantised: <= 3% of F0 ~ 0.04)
    np.testing.assert_allclose(base, want, atol=CODE + 0.005)
    rough = np.asarray(mat.metallicRoughnessTexture.convert("RGB")).reshape(-1, 3)[at] / 255.0
    alpha = np.asarray(maps.alpha).min(1)
    np.testing.assert_allclose(rough[:, 1], np.sqrt(alpha), atol=0.5 * CODE + 1e-9)
    assert np.all(rough[:, 2] == 0)  # metallic 0


def test_tangents_are_unit_orthogonal_and_handed(tmp_path):
    """TANGENT: unit xyz orthogonal to NORMAL, w = +-1; on the quad T = +x = dP/du, and w (N x T) points up the
    image (dP/dv): w = +1, and -1 when the UVs are mirrored."""
    for mirror, w in ((False, 1.0), (True, -1.0)):
        mesh = _quad(mirror)
        surface = stage.texel_samples(mesh, RES)
        path = tmp_path / f"mirror-{mirror}.glb"
        write_gltf(material_maps(surface, 0.5, 0.04, 0.3), path, mesh=mesh, surface=surface)
        asset = read_gltf(path)
        t, n = asset.tangents.astype(np.float64), asset.normals.astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(t[:, :3], axis=1), 1.0, atol=1e-6)
        assert np.abs(np.sum(t[:, :3] * n, 1)).max() < 1e-6
        np.testing.assert_array_equal(t[:, 3], w)
        np.testing.assert_allclose(t[:, :3], np.tile([w, 0.0, 0.0], (len(t), 1)), atol=1e-6)  # dP/du = w x
        b = np.cross(n, t[:, :3]) * t[:, 3:]
        np.testing.assert_allclose(b, np.tile([0.0, 0.0, -1.0], (len(t), 1)), atol=1e-6)  # dP/dv: v runs along -z


@pytest.mark.parametrize("tilt_axis", ["tangent", "bitangent"])
def test_normal_map_decodes_a_known_tilt(tilt_axis, tmp_path):
    """Normals tilted 20 degrees toward +u (red) or +v, up the image (green), come back from the texture as
    (sin 20, 0, cos 20) / (0, sin 20, cos 20), and through gltf_maps as the fitted normal, within 0.5 degrees."""
    mesh = _quad()
    surface = stage.texel_samples(mesh, RES)
    maps = _maps(surface, tilt_axis)
    write_gltf(maps, tmp_path / "t.glb", mesh=mesh, surface=surface)
    asset = read_gltf(tmp_path / "t.glb")
    tex = asset.images[asset.doc["textures"][asset.doc["materials"][0]["normalTexture"]["index"]]["source"]]
    c = tex.reshape(-1, 3)[np.asarray(surface.texel_index)] / 127.5 - 1.0
    c /= np.linalg.norm(c, axis=1, keepdims=True)
    s, k = np.sin(np.radians(TILT_DEG)), np.cos(np.radians(TILT_DEG))
    want = np.array([s, 0.0, k] if tilt_axis == "tangent" else [0.0, s, k])
    assert np.degrees(np.arccos(np.clip(c @ want, -1, 1))).max() < NORMAL_DEG
    back = np.asarray(gltf_maps(asset, surface).normal, np.float64)
    cos = np.sum(back * np.asarray(maps.normal, np.float64), 1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < NORMAL_DEG


def test_every_rung_reads_back_within_quantisation(quad):
    """gltf_maps(extras=True) gives the maps back: F0 within 3% (8-bit sRGB of F0 / F0_max), alpha within 2%
    (8-bit sqrt), the anisotropic alphas along the fitted axis, rungs and mean free path exact to 16 bits;
    extras=False gives the rungs glTF draws (lambert, ggx, ggx_aniso)."""
    path, _, surface, maps, export = quad
    back = gltf_maps(path, surface, extras=True)
    model = np.asarray(maps.model)
    np.testing.assert_array_equal(np.asarray(back.model), model)
    spec = model != LAMBERT
    np.testing.assert_allclose(np.asarray(back.rho_s)[spec], np.asarray(maps.rho_s)[spec], rtol=0.03)
    assert np.all(np.asarray(back.rho_s)[~spec] == 0)
    a0, a1 = np.asarray(maps.alpha), np.asarray(back.alpha)
    # back's alpha is along its decoded axis (that of the larger alpha): compare as (max, min)
    np.testing.assert_allclose(np.sort(a1, 1), np.sort(a0, 1), rtol=0.02)
    aniso = model >= GGX_ANISO
    axis0 = np.where((a0[:, 0] >= a0[:, 1])[:, None], np.asarray(maps.tangent),
                     np.cross(np.asarray(maps.normal), np.asarray(maps.tangent)))
    cos = np.abs(np.sum(axis0[aniso] * np.asarray(back.tangent)[aniso], 1))
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.0
    sss = model == SUBSURFACE
    np.testing.assert_allclose(np.asarray(back.mfp)[sss], np.asarray(maps.mfp)[sss], atol=3.0 / 65535)
    drawn = np.asarray(gltf_maps(path, surface).model)
    np.testing.assert_array_equal(drawn, np.where(model == LAMBERT, LAMBERT, np.where(aniso, GGX_ANISO, GGX)))
    rho_d = np.asarray(back.rho_d)
    lin = np.asarray(srgb_decode(np.asarray(srgb_encode(np.asarray(maps.rho_d, np.float64)))))
    # within the 8-bit sRGB step at each value (below 0.8 a code is < 1.3% of the value above 0.05)
    np.testing.assert_allclose(rho_d, lin, rtol=0.03, atol=1e-3)
    assert export.clamped == {"f0": 0, "base_color": 0, "normal": 0}


def test_f0_max_clamps_and_counts(quad, tmp_path):
    """f0_max: the specular colour spans F0 up to it; specular texels above are clamped to it and counted; the
    others read back within 8-bit sRGB (finer than the default's steps, whose range is the largest F0)."""
    _, mesh, surface, maps, _ = quad
    spec = np.asarray(maps.model) != LAMBERT
    rho_s = np.asarray(maps.rho_s)[:, 0]
    export = write_gltf(maps, tmp_path / "f.glb", mesh=mesh, surface=surface, f0_max=0.04)
    assert export.clamped["f0"] == int(np.sum(spec & (rho_s > 0.04))) > 0
    back = np.asarray(gltf_maps(tmp_path / "f.glb", surface).rho_s)[:, 0]
    np.testing.assert_allclose(back[spec], np.minimum(rho_s, 0.04)[spec], rtol=0.015)
    with pytest.raises(ValueError, match="f0_max"):
        write_gltf(maps, tmp_path / "g.glb", mesh=mesh, surface=surface, f0_max=0.0)


def test_unseen_and_off_chart_texels_hold_a_neighbour_not_a_constant(tmp_path):
    """Samples no camera saw get the nearest seen sample's material; texels off the UV charts their nearest
    sample texel's values; coverage_alpha cuts the unseen ones out (alpha 0, alphaMode MASK)."""
    mesh = _quad(uv_scale=0.5)  # the charts cover a quarter of the grid
    surface = stage.texel_samples(mesh, RES)
    P = surface.num_samples
    rho_d = np.tile([0.2, 0.4, 0.6], (P, 1))
    seen = np.asarray(surface.position)[:, 0] < 0  # the half at x < 0
    rho_d[~seen] = [0.9, 0.1, 0.1]  # what the unseen samples held: not to be exported
    maps = material_maps(surface, rho_d, 0.04, 0.3)
    export = write_gltf(maps, tmp_path / "u.glb", mesh=mesh, surface=surface, seen=seen, coverage_alpha=True)
    assert (export.seen, export.filled) == (int(seen.sum()), int((~seen).sum()))
    asset = read_gltf(tmp_path / "u.glb")
    mat = asset.doc["materials"][0]
    assert mat["alphaMode"] == "MASK"
    base = asset.images[asset.doc["textures"][mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]]
    assert base.shape == (RES, RES, 4)
    rgb = base[..., :3].reshape(-1, 3)
    # every texel of the grid, on the charts or not, holds the seen colour
    np.testing.assert_array_equal(rgb, np.tile(rgb[np.asarray(surface.texel_index)[seen][0]], (RES * RES, 1)))
    alpha = base[..., 3].reshape(-1)[np.asarray(surface.texel_index)]
    np.testing.assert_array_equal(alpha, np.where(seen, 255, 0))


def test_khronos_validator_accepts_the_quad(quad):
    """Zero errors and zero warnings from the Khronos glTF Validator on an export with every rung."""
    issues = _validate(quad[0])
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_relight_export_of_a_demo(demo_output, tmp_path, capsys):
    """Done when of issue 31 item 1: `relight export` of `relight demo`'s maps writes a .glb that trimesh reads
    back (the head's vertices and triangles) and the Khronos validator accepts with no errors; misuse is one
    line naming the file."""
    import trimesh

    from relight.cli import main
    from relight.io import load_texel_maps

    out = tmp_path / "head.glb"
    assert main(["export", str(demo_output / "maps"), "--gltf", str(out)]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    head = load_texel_maps(demo_output / "maps").mesh
    geom = trimesh.load(out, force="mesh", process=False)
    np.testing.assert_allclose(geom.vertices * 1e3, head.vertices, atol=1e-3)
    np.testing.assert_array_equal(geom.faces, head.faces)
    assert main(["export", str(demo_output), "--gltf", str(tmp_path / "x.glb")]) == 1
    assert "its maps/ is one" in capsys.readouterr().err
    assert main(["export", str(demo_output / "maps"), "--gltf", str(tmp_path / "head.gltf")]) == 1
    assert "must end in .glb" in capsys.readouterr().err
    issues = _validate(out)  # last: it skips where the validator is absent
    assert issues["numErrors"] == 0, issues["messages"]
