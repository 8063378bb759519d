"""The results viewer: one self-contained HTML page (``index.html``) per result folder, opened from
``file://`` in any browser (no server, no network: images are ``data:`` URIs, CSS and script inline).

* :func:`write_index` / :func:`page_html`: the page of a folder: the relit subject with an
  environment-rotation slider (:class:`Sweep` rows), report.md as HTML, truth | fit | error where a truth
  map set is at hand, the texel-space maps, every other PNG, settings.json.
* :func:`capture_sweep` (image-based, Debevec et al. 2000), :func:`photo_sweep`, :func:`maps_sweep`
  (model-based, ``relight.render.turntable``), :func:`frames_sweep` (frames on disk): the slider's rows.
* :func:`folder_sweeps` / :func:`map_set_sweeps`: the sweeps a folder supports, found from what it records
  (a map set's own capture is relit image-based first; the model-based sweep is the fallback, or an extra row);
  :func:`render_sweeps`: the slider of a ``relight.render.render_folder`` output.
* :func:`markdown_html`: the Markdown subset of the project's reports as HTML.
* The page's "3D view" of a map set (WebGL2, ``relight/data/viewer3d.js``): :func:`view3d_method` and
  :func:`view3d_envmap` (the ``relight.render.Fast`` precomputation it embeds and evaluates), :func:`view3d_data`
  (what a page embeds), :func:`decimate_mesh` (seam-safe vertex clustering, above ``VIEW3D_MAX_TRIANGLES``),
  :func:`vertex_curvature`.

``relight view RESULT_DIR`` (docs/cli.md) writes the page; every command writes one into its output folder.
"""

from ._markdown import markdown_html as markdown_html
from ._mesh3d import decimate_mesh as decimate_mesh
from ._mesh3d import vertex_curvature as vertex_curvature
from ._page import INDEX as INDEX
from ._page import data_uri as data_uri
from ._page import page_html as page_html
from ._page import write_index as write_index
from ._page3d import VIEW3D_ENV_WIDTH as VIEW3D_ENV_WIDTH
from ._page3d import VIEW3D_MAX_TEXTURE as VIEW3D_MAX_TEXTURE
from ._page3d import VIEW3D_MAX_TRIANGLES as VIEW3D_MAX_TRIANGLES
from ._page3d import view3d_data as view3d_data
from ._page3d import view3d_envmap as view3d_envmap
from ._page3d import view3d_method as view3d_method
from ._sweep import DEFAULT_FRAMES as DEFAULT_FRAMES
from ._sweep import DEFAULT_SIZE as DEFAULT_SIZE
from ._sweep import Sweep as Sweep
from ._sweep import capture_sweep as capture_sweep
from ._sweep import folder_sweeps as folder_sweeps
from ._sweep import frames_sweep as frames_sweep
from ._sweep import map_set_sweeps as map_set_sweeps
from ._sweep import maps_sweep as maps_sweep
from ._sweep import photo_sweep as photo_sweep
from ._sweep import preview_envmap as preview_envmap
from ._sweep import render_sweeps as render_sweeps
from ._sweep import sweep_angles as sweep_angles
from ._sweep import sweep_camera as sweep_camera

__all__ = ["DEFAULT_FRAMES", "DEFAULT_SIZE", "INDEX", "VIEW3D_ENV_WIDTH", "VIEW3D_MAX_TEXTURE", "VIEW3D_MAX_TRIANGLES",
           "Sweep", "capture_sweep", "data_uri", "decimate_mesh", "folder_sweeps", "frames_sweep", "map_set_sweeps",
           "maps_sweep", "markdown_html", "page_html", "photo_sweep", "preview_envmap", "render_sweeps",
           "sweep_angles", "sweep_camera", "vertex_curvature", "view3d_data", "view3d_envmap", "view3d_method",
           "write_index"]
