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

``relight view RESULT_DIR`` (docs/cli.md) writes the page; every command writes one into its output folder.
"""

from ._markdown import markdown_html as markdown_html
from ._page import INDEX as INDEX
from ._page import data_uri as data_uri
from ._page import page_html as page_html
from ._page import write_index as write_index
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

__all__ = ["DEFAULT_FRAMES", "DEFAULT_SIZE", "INDEX", "Sweep", "capture_sweep", "data_uri", "folder_sweeps",
           "frames_sweep", "map_set_sweeps", "maps_sweep", "markdown_html", "page_html",
           "photo_sweep", "preview_envmap", "render_sweeps", "sweep_angles", "sweep_camera", "write_index"]
