"""Result sets and atomic writes: a command's output folder (a fit's map set, a
render's images, a capture folder or store) written as one unit beside its
place, listed in a SHA-256 manifest, swapped in whole and locked while it is
written; single files written atomically. Every ``relight`` writer and reader
of such folders uses this room. See docs/relight_io.md ("Result sets")."""

from ._atomic import atomic_path as atomic_path
from ._atomic import atomic_write_bytes as atomic_write_bytes
from ._atomic import atomic_write_text as atomic_write_text
from ._errors import FolderLockedError as FolderLockedError
from ._errors import ForeignFolderError as ForeignFolderError
from ._errors import NoSpaceError as NoSpaceError
from ._errors import ResultSetError as ResultSetError
from ._errors import WriteError as WriteError
from ._errors import no_space_error as no_space_error
from ._errors import writing as writing
from ._format import format_version as format_version
from ._lock import FolderLock as FolderLock
from ._output import earlier_output as earlier_output
from ._reseal import reseal as reseal
from ._resultset import MANIFEST as MANIFEST
from ._resultset import ResultSet as ResultSet
from ._resultset import check_output_folder as check_output_folder
from ._resultset import clean_stale as clean_stale
from ._resultset import commit_point as commit_point
from ._resultset import describe_folder as describe_folder
from ._resultset import file_digest as file_digest
from ._resultset import folder_mode as folder_mode
from ._resultset import is_result_set as is_result_set
from ._resultset import open_result_set as open_result_set
from ._resultset import result_set as result_set
from ._resultset import swap_into as swap_into
from ._resultset import write_manifest as write_manifest

__all__ = [
    "MANIFEST",
    "FolderLock",
    "FolderLockedError",
    "ForeignFolderError",
    "NoSpaceError",
    "ResultSet",
    "ResultSetError",
    "WriteError",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_folder",
    "clean_stale",
    "commit_point",
    "describe_folder",
    "earlier_output",
    "file_digest",
    "folder_mode",
    "format_version",
    "is_result_set",
    "no_space_error",
    "open_result_set",
    "reseal",
    "result_set",
    "swap_into",
    "write_manifest",
    "writing",
]
