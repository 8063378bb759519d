"""What the ``relight`` commands share, gathered in one namespace for their imports: the error type and the
checks before a run (``_guard``), the shared flags (``_flags``), progress bars (``_progress``), the spellings of
rigs, cameras and materials (``_specs``), the output folder (``_output``) and the compilation cache
(``_cache``). Library logic lives in the library (``relight.results``, ``relight.io``, ``relight.materials``,
``stage``); these modules only parse, call it and print. Importing this module imports no JAX (a command's
``--help`` builds its parser from it: tests/relight/test_cli_ux.py)."""

from ._cache import CACHE_ENV as CACHE_ENV
from ._cache import CACHE_MIN_COMPILE_S as CACHE_MIN_COMPILE_S
from ._cache import cache_dir as cache_dir
from ._cache import compile_cache as compile_cache
from ._cache import default_cache_dir as default_cache_dir
from ._flags import INDEX_FRAMES as INDEX_FRAMES
from ._flags import INDEX_SIZE as INDEX_SIZE
from ._flags import MIN_IMAGE_SIZE as MIN_IMAGE_SIZE
from ._flags import PREVIEW_MIN_PX as PREVIEW_MIN_PX
from ._flags import RIG_AXES as RIG_AXES
from ._flags import RIG_UNITS as RIG_UNITS
from ._flags import add_envmap as add_envmap
from ._flags import add_image_size as add_image_size
from ._flags import add_index_flag as add_index_flag
from ._flags import add_mesh_flags as add_mesh_flags
from ._flags import add_out as add_out
from ._flags import add_photo_texel_flags as add_photo_texel_flags
from ._flags import add_rig_file_flags as add_rig_file_flags
from ._flags import at_least as at_least
from ._flags import envmap_path as envmap_path
from ._flags import finish_parser as finish_parser
from ._flags import mesh_from_args as mesh_from_args
from ._flags import photo_mesh_from_args as photo_mesh_from_args
from ._flags import refuse_photo_flags as refuse_photo_flags
from ._flags import warn_mesh_size as warn_mesh_size
from ._guard import CLIError as CLIError
from ._guard import check_numbers as check_numbers
from ._guard import guarded as guarded
from ._output import check_out as check_out
from ._output import output_set as output_set
from ._output import upscale_nearest as upscale_nearest
from ._output import write_index_page as write_index_page
from ._output import write_json as write_json
from ._output import write_map_previews as write_map_previews
from ._output import write_preview as write_preview
from ._output import write_settings as write_settings
from ._output import writing as writing
from ._progress import Bar as Bar
from ._progress import bar as bar
from ._progress import summary as summary
from ._specs import parse_cameras as parse_cameras
from ._specs import parse_rig as parse_rig
from ._specs import preset_mean_free_path as preset_mean_free_path


def __getattr__(name: str):
    # PEP 562: SUBSURFACE_PRESETS (the names --subsurface takes) reads skin_bssrdf, and so JAX, when asked for.
    if name == "SUBSURFACE_PRESETS":
        from . import _specs

        return _specs.SUBSURFACE_PRESETS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
