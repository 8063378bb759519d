"""stage.read_metashape_xml against Metashape's frame-camera formula (user manual, Appendix C "Camera models"),
written here in numpy: an exported chunk's cameras project known world points where Metashape would put them
(to 1e-3 px), through the chunk's similarity transform, the affinity and skew terms and Metashape's P1 / P2;
unaligned cameras are skipped with a warning; every refusal names the file and the field. And the one
cross-format check: the same cameras written as COLMAP (text and binary), OpenCV JSON and YAML and Metashape
XML give the same projections to 1e-3 px.

``write_metashape_xml`` is also a fixture of tests/relight/test_cli_cameras.py."""

import jax.numpy as jnp
import numpy as np
import pytest

import stage

from .test_calib_colmap import write_colmap_binary, write_colmap_text
from .test_calib_opencv import write_opencv_json, write_opencv_yaml

PX_TOL = 1e-3  # Camera.project stores K, R, t in float32 (~1e-4 px here); the formats' formulas run in float64


def _text(values):
    return " ".join(repr(float(v)) for v in np.ravel(values))


def write_metashape_xml(path, sensors, cameras, chunk=None, components=None):
    """An Agisoft XML camera export. ``sensors`` = {id: dict(w, h, type, calibration terms f, cx, cy, b1, b2, k1..,
    p1.., or extra XML)}, ``cameras`` = [(id, label, sensor_id, 4x4 camera-to-chunk or None, component_id or
    None)], ``chunk`` / ``components[id]`` = (R 3x3, T 3, s) similarity transforms (chunk to world)."""
    def similarity(tr):
        R, T, s = tr
        return (f"<transform><rotation locked=\"true\">{_text(R)}</rotation><translation locked=\"true\">{_text(T)}"
                f"</translation><scale locked=\"true\">{float(s)!r}</scale></transform>")

    xml = ['<?xml version="1.0" encoding="UTF-8"?>', '<document version="2.0.0">',
           '  <chunk label="Chunk 1" enabled="true">', f'    <sensors next_id="{len(sensors)}">']
    for sid, s in sensors.items():
        terms = "".join(f"<{k}>{float(v)!r}</{k}>" for k, v in s.items() if k not in ("w", "h", "type", "extra"))
        xml += [f'      <sensor id="{sid}" label="lens {sid}" type="{s.get("type", "frame")}">',
                f'        <resolution width="{s["w"]}" height="{s["h"]}"/>',
                '        <property name="pixel_width" value="0.0039"/>',
                f'        <calibration type="{s.get("type", "frame")}" class="initial">'
                f'<resolution width="{s["w"]}" height="{s["h"]}"/><f>{s.get("f", 1000.0) * 1.1!r}</f></calibration>',
                f'        <calibration type="{s.get("type", "frame")}" class="adjusted">'
                f'<resolution width="{s["w"]}" height="{s["h"]}"/>{terms}{s.get("extra", "")}</calibration>',
                '      </sensor>']
    xml.append("    </sensors>")
    if components:
        xml.append('    <components next_id="2" active_id="0">')
        xml += [f'      <component id="{cid}" label="Component {cid}">{similarity(tr)}</component>'
                for cid, tr in components.items()]
        xml.append("    </components>")
    xml.append('    <cameras next_id="9" next_group_id="1">')
    xml.append('      <group id="0" label="Folder 1" type="folder">')
    for cid, label, sid, M, comp in cameras:
        attrs = f'id="{cid}" sensor_id="{sid}" label="{label}"' + ("" if comp is None else f' component_id="{comp}"')
        body = "" if M is None else f"<transform>{_text(M)}</transform>"
        xml.append(f"        <camera {attrs}>{body}<orientation>1</orientation></camera>")
    xml += ["      </group>", "    </cameras>"]
    if chunk is not None:
        xml.append("    " + similarity(chunk))
    xml += ["  </chunk>", "</document>"]
    path.write_text("\n".join(xml) + "\n")
    return path


def metashape_project(sensor, M, chunk, points):
    """Metashape's frame camera (Appendix C): world X -> chunk p = R^T (X - T) / s -> camera
    (X, Y, Z) = M^-1 p, x = X/Z, y = Y/Z, x' = x L + P1 (r^2 + 2x^2) + 2 P2 x y,
    y' = y L + P2 (r^2 + 2y^2) + 2 P1 x y, u = w/2 + cx + x' f + x' B1 + y' B2, v = h/2 + cy + y' f."""
    R, T, s = chunk
    p = (points - T) @ R / s
    xc = (np.c_[p, np.ones(len(p))] @ np.linalg.inv(M).T)[:, :3]
    x, y = xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2]
    g = {k: sensor.get(k, 0.0) for k in ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "p1", "p2")}
    r2 = x * x + y * y
    L = 1 + g["k1"] * r2 + g["k2"] * r2**2 + g["k3"] * r2**3
    xd = x * L + g["p1"] * (r2 + 2 * x * x) + 2 * g["p2"] * x * y
    yd = y * L + g["p2"] * (r2 + 2 * y * y) + 2 * g["p1"] * x * y
    u = sensor["w"] * 0.5 + g["cx"] + xd * g["f"] + xd * g["b1"] + yd * g["b2"]
    v = sensor["h"] * 0.5 + g["cy"] + yd * g["f"]
    return np.stack([u, v], axis=-1)


def rotation(axis, angle):
    """The rotation by ``angle`` radians about ``axis``."""
    k = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def camera_to_chunk(eye, chunk):
    """A 4x4 camera-to-chunk transform looking from world ``eye`` at the world origin (y down in the image)."""
    R, T, s = chunk
    fwd = -np.asarray(eye, np.float64) / np.linalg.norm(eye)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    cam_to_world = np.stack([right, np.cross(fwd, right), fwd], axis=1)
    M = np.eye(4)
    M[:3, :3] = R.T @ cam_to_world
    M[:3, 3] = R.T @ (np.asarray(eye, np.float64) - T) / s
    return M


SENSOR = {"w": 1200, "h": 900, "f": 1500.0, "cx": 12.5, "cy": -7.25, "b1": 3.0, "b2": 0.8, "k1": -0.09,
          "k2": 0.04, "k3": -0.01, "p1": 0.0011, "p2": -0.0007}
CHUNK = (rotation([0.3, 1.0, -0.2], 0.7), np.array([0.4, -1.2, 2.5]), 0.37)  # the world is in metres


def test_cameras_project_as_metashape_does(tmp_path):
    eyes = {"IMG_0001": (0.2, 0.1, 1.6), "IMG_0002": (-1.4, 0.3, 0.5), "IMG_0003": (0.9, -0.6, -1.2)}
    cams = [(k, label, 0, camera_to_chunk(eye, CHUNK), None) for k, (label, eye) in enumerate(eyes.items())]
    path = write_metashape_xml(tmp_path / "cameras.xml", {0: SENSOR}, cams, CHUNK)
    out = stage.read_metashape_xml(path, "m")
    assert list(out) == list(eyes)
    X = np.random.default_rng(1).uniform(-0.15, 0.15, size=(64, 3))
    for _, label, _, M, _ in cams:
        pix, depth = out[label].project(X * 1000.0)
        np.testing.assert_allclose(np.asarray(pix), metashape_project(SENSOR, M, CHUNK, X), atol=PX_TOL, rtol=0)
        assert np.all(np.asarray(depth) > 0) and (out[label].width, out[label].height) == (1200, 900)
    K = np.asarray(out["IMG_0001"].K)
    np.testing.assert_allclose(K, [[1503.0, 0.8, 612.5], [0, 1500.0, 442.75], [0, 0, 1]], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(out["IMG_0001"].dist), [-0.09, 0.04, -0.0007, 0.0011, -0.01], rtol=1e-6)


def test_a_component_transform_is_used_for_its_cameras(tmp_path):
    comp = (rotation([1.0, 0.0, 0.2], -0.4), np.array([1.0, 0.0, -0.5]), 2.0)
    cams = [(0, "a", 0, camera_to_chunk((0.1, 0.2, 1.5), comp), 0),
            (1, "b", 0, camera_to_chunk((0, 0, 2.0), CHUNK), None)]
    path = write_metashape_xml(tmp_path / "c.xml", {0: SENSOR}, cams, CHUNK, components={0: comp})
    out = stage.read_metashape_xml(path, 1000.0)
    X = np.random.default_rng(2).uniform(-0.1, 0.1, size=(32, 3))
    for (_, label, _, M, _), tr in zip(cams, (comp, CHUNK), strict=True):
        pix, _ = out[label].project(X * 1000.0)
        np.testing.assert_allclose(np.asarray(pix), metashape_project(SENSOR, M, tr, X), atol=PX_TOL, rtol=0)


def test_unaligned_cameras_are_skipped_with_a_warning(tmp_path):
    cams = [(0, "a", 0, camera_to_chunk((0, 0, 2.0), CHUNK), None), (1, "lost1", 0, None, None),
            (2, "lost2", 0, None, None)]
    path = write_metashape_xml(tmp_path / "c.xml", {0: SENSOR}, cams, CHUNK)
    with pytest.warns(UserWarning, match=r"c.xml: 2 camera\(s\) without a transform \(not aligned\) skipped: "
                                         r"lost1, lost2"):
        out = stage.read_metashape_xml(path, "m")
    assert list(out) == ["a"]
    path = write_metashape_xml(tmp_path / "none.xml", {0: SENSOR}, cams[1:], CHUNK)
    with pytest.warns(UserWarning, match="lost1"), pytest.raises(ValueError, match="none.xml: no aligned camera"):
        stage.read_metashape_xml(path, "m")


@pytest.mark.parametrize("sensor, match", [
    (dict(SENSOR, type="fisheye"), r"sensor '0' \('lens 0'\): sensor type 'fisheye' is not supported"),
    (dict(SENSOR, type="spherical"), r"sensor '0' \('lens 0'\): sensor type 'spherical' is not supported"),
    (dict(SENSOR, k4=0.001), r"sensor '0' \('lens 0'\): field 'k4' is not zero"),
    (dict(SENSOR, p3=0.1), r"sensor '0' \('lens 0'\): field 'p3' is not zero"),
    (dict(SENSOR, fx=1500.0), r"sensor '0' \('lens 0'\): field 'fx': an older PhotoScan calibration"),
    ({k: v for k, v in SENSOR.items() if k != "f"}, r"sensor '0' \('lens 0'\): missing field 'f'"),
    (dict(SENSOR, extra="<k2>two</k2>"), r"sensor '0' \('lens 0'\): field 'k2' must be a number"),
    (dict(SENSOR, f=-5.0), r"camera 'a': field 'K' needs positive focal lengths"),
])
def test_bad_sensors_are_refused_naming_the_sensor(tmp_path, sensor, match):
    if "extra" in sensor:
        sensor = {k: v for k, v in sensor.items() if k != "k2"}
    path = write_metashape_xml(tmp_path / "c.xml", {0: sensor}, [(0, "a", 0, camera_to_chunk((0, 0, 2.0), CHUNK),
                                                                  None)], CHUNK)
    with pytest.raises(ValueError, match=rf"c.xml: {match}"):
        stage.read_metashape_xml(path, "m")


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("<chunk ", "<chunk/><chunk "), r"c.xml: expected one <chunk>, got 2"),
    (lambda t: t.replace("</document>", ""), r"c.xml: not valid XML"),
    (lambda t: t.replace("<document", "<!DOCTYPE d [<!ENTITY x 'y'>]><document"), r"c.xml: a DOCTYPE"),
    (lambda t: t.replace("<document", "<doc").replace("</document>", "</doc>"), r"c.xml: expected a Metashape"),
    (lambda t: t.replace('sensor_id="0"', 'sensor_id="5"'), r"c.xml: camera 'a': field 'sensor_id': sensor '5'"),
    (lambda t: t.replace("<scale locked=\"true\">0.37", "<scale locked=\"true\">-0.37"),
     r"c.xml: chunk 'transform': field 'scale' must be positive"),
    (lambda t: t.replace("</translation>", " 9</translation>", 1), r"c.xml: chunk 'transform': field 'translation'"),
    (lambda t: t.replace("<transform>", "<transform>1 ", 1), r"c.xml: camera 'a': field 'transform' must be 16"),
    (lambda t: t.replace(" 1.0</transform>", " 2.0</transform>", 1), r"c.xml: camera 'a': .*end with the row 0 0 0 1"),
])
def test_malformed_files_name_the_file_and_field(tmp_path, edit, match):
    path = write_metashape_xml(tmp_path / "c.xml", {0: SENSOR}, [(0, "a", 0, camera_to_chunk((0, 0, 2.0), CHUNK),
                                                                  None)], CHUNK)
    path.write_text(edit(path.read_text()))
    with pytest.raises(ValueError, match=match):
        stage.read_metashape_xml(path, "m")


def test_a_missing_file_and_bad_units(tmp_path):
    with pytest.raises(FileNotFoundError, match="gone.xml: no such Metashape camera file"):
        stage.read_metashape_xml(tmp_path / "gone.xml", "m")
    path = write_metashape_xml(tmp_path / "c.xml", {0: SENSOR}, [(0, "a", 0, camera_to_chunk((0, 0, 2.0), CHUNK),
                                                                  None)], CHUNK)
    for units in (0, float("nan"), "yard"):
        with pytest.raises(ValueError, match="mm_per_unit"):
            stage.read_metashape_xml(path, units)


# ------------------------------------------------------------------------------------------ one rig, four formats


def truth_rig():
    """Three cameras in the Camera's own terms (K with the top-left pixel's centre at (0.5, 0.5), OpenCV's
    (k1, k2, p1, p2, k3) with k3 = 0, which COLMAP's OPENCV model lacks; R, t in mm), about 1.5 m from the
    origin."""
    rig = {}
    for k, (eye, f, dist) in enumerate((((200.0, 100.0, 1500.0), (1400.0, 1380.0), (-0.1, 0.05, 0.001, -0.002, 0)),
                                        ((-1300.0, 200.0, 700.0), (1500.0, 1500.0), (0.02, 0.0, 0.0, 0.0, 0)),
                                        ((900.0, -500.0, -1100.0), (1350.0, 1360.0), (0.0, 0.0, 0.0, 0.0, 0)))):
        K = np.array([[f[0], 0.0, 641.0 + k], [0.0, f[1], 478.5 - k], [0.0, 0.0, 1.0]])
        R = camera_to_chunk(eye, (np.eye(3), np.zeros(3), 1.0))[:3, :3].T  # world to camera, looking at 0
        rig[f"cam{k:03d}"] = dict(K=K, dist=np.array(dist, np.float64), R=R, t=-R @ np.asarray(eye), w=1280, h=960)
    return rig


def write_every_format(folder, rig):
    """The rig as a COLMAP model (metres, text and binary), OpenCV JSON and YAML (cm) and Metashape XML (metres,
    with a chunk transform); returns {format: (path, mm_per_unit)}."""
    colmap_cams, images = [], []
    for k, (name, c) in enumerate(rig.items()):
        K, d = c["K"], c["dist"]
        colmap_cams.append((k + 1, "OPENCV", c["w"], c["h"], [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d[:4]]))
        R = c["R"]
        w = np.sqrt(1 + np.trace(R)) / 2
        q = [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w)]
        images.append((k + 1, q, c["t"] / 1000.0, k + 1, name, None))
    write_colmap_text(folder / "colmap_txt", colmap_cams, images)
    write_colmap_binary(folder / "colmap_bin", colmap_cams, images)
    opencv = {n: {"K": c["K"] - [[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]], "dist": c["dist"], "R": c["R"],
                  "t": c["t"] / 10.0, "width": c["w"], "height": c["h"]} for n, c in rig.items()}
    write_opencv_json(folder / "opencv.json", opencv)
    write_opencv_yaml(folder / "opencv.yml", opencv)
    sensors, cams = {}, []
    for k, (name, c) in enumerate(rig.items()):
        K, d = c["K"], c["dist"]
        sensors[k] = dict(w=c["w"], h=c["h"], f=K[1, 1], b1=K[0, 0] - K[1, 1], cx=K[0, 2] - c["w"] / 2,
                          cy=K[1, 2] - c["h"] / 2, k1=d[0], k2=d[1], k3=d[4], p1=d[3], p2=d[2])
        Rk, T, s = CHUNK
        M = np.eye(4)
        M[:3, :3] = Rk.T @ c["R"].T
        M[:3, 3] = Rk.T @ ((-c["R"].T @ c["t"]) / 1000.0 - T) / s
        cams.append((k, name, k, M, None))
    write_metashape_xml(folder / "cameras.xml", sensors, cams, CHUNK)
    return {"colmap text": (folder / "colmap_txt", "m"), "colmap binary": (folder / "colmap_bin", "m"),
            "opencv json": (folder / "opencv.json", "cm"), "opencv yaml": (folder / "opencv.yml", "cm"),
            "metashape": (folder / "cameras.xml", "m")}


READERS = {"colmap": stage.read_colmap, "opencv": stage.read_opencv_calibration, "metashape": stage.read_metashape_xml}


def test_one_rig_in_every_format_projects_the_same(tmp_path):
    rig = truth_rig()
    X = np.random.default_rng(3).uniform(-150.0, 150.0, size=(64, 3))
    expected = {}
    for name, c in rig.items():
        cam = stage.Camera(K=jnp.asarray(c["K"], jnp.float32), R=jnp.asarray(c["R"], jnp.float32),
                           t=jnp.asarray(c["t"], jnp.float32), width=c["w"], height=c["h"],
                           dist=jnp.asarray(c["dist"], jnp.float32))
        expected[name] = np.asarray(cam.project(X)[0])
    for fmt, (path, units) in write_every_format(tmp_path, rig).items():
        cams = READERS[fmt.split()[0]](path, units)
        assert list(cams) == list(rig), fmt
        for name in rig:
            pix = np.asarray(cams[name].project(X)[0])
            np.testing.assert_allclose(pix, expected[name], atol=PX_TOL, rtol=0, err_msg=f"{fmt}: {name}")
