"""stage: the light stage as a simulator — rigs, cameras, meshes to surface
samples (texels or pixels), visibility, sensor model, polarisation and
gradient illumination, and one-light-at-a-time capture simulation. The one
OLAT forward model (``incident_light``, ``to_local``, ``reflected_radiance``,
``subsurface_irradiance``, ``subsurface_exitance``) lives here and is shared
by simulation, fitting and rendering. See docs/stage.md."""

from ._camera import Camera as Camera
from ._camera import camera_from_dict as camera_from_dict
from ._camera import camera_ring as camera_ring
from ._camera import camera_to_dict as camera_to_dict
from ._camera import load_cameras as load_cameras
from ._camera import look_at as look_at
from ._camera import orthographic as orthographic
from ._camera import save_cameras as save_cameras
from ._capture import Capture as Capture
from ._forward import incident_light as incident_light
from ._forward import reflected_radiance as reflected_radiance
from ._forward import reflected_radiance_lights as reflected_radiance_lights
from ._forward import subsurface_exitance as subsurface_exitance
from ._forward import subsurface_irradiance as subsurface_irradiance
from ._forward import to_local as to_local
from ._gradient import PATTERNS as PATTERNS
from ._gradient import diffuse_normals as diffuse_normals
from ._gradient import gradient_images as gradient_images
from ._gradient import gradient_weights as gradient_weights
from ._gradient import specular_normals as specular_normals
from ._image import image_samples as image_samples
from ._mesh import HEAD_SCALE_MM as HEAD_SCALE_MM
from ._mesh import Mesh as Mesh
from ._mesh import MeshReport as MeshReport
from ._mesh import check_mesh as check_mesh
from ._mesh import head_mesh_path as head_mesh_path
from ._mesh import load_head as load_head
from ._mesh import load_mesh as load_mesh
from ._progress import Phase as Phase
from ._progress import Progress as Progress
from ._rig import Gonioreflectometer as Gonioreflectometer
from ._rig import Rig as Rig
from ._rig import calibrate as calibrate
from ._rig import directional_rig as directional_rig
from ._rig import fibonacci_sphere as fibonacci_sphere
from ._rig import geodesic_dome as geodesic_dome
from ._rig import gonioreflectometer as gonioreflectometer
from ._rig import light_stage_x as light_stage_x
from ._rig import light_stage_x_faces as light_stage_x_faces
from ._rig import make_rig as make_rig
from ._rig import voronoi_solid_angles as voronoi_solid_angles
from ._rig_io import load_rig as load_rig
from ._rig_io import rig_from_dict as rig_from_dict
from ._rig_io import rig_to_dict as rig_to_dict
from ._rig_io import save_rig as save_rig
from ._sensor import Sensor as Sensor
from ._sensor import sense as sense
from ._simulate import DEPOLARIZED_TRANSMISSION as DEPOLARIZED_TRANSMISSION
from ._simulate import Subsurface as Subsurface
from ._simulate import shading_directions as shading_directions
from ._simulate import simulate as simulate
from ._simulate import simulate_chunks as simulate_chunks
from ._simulate import split_material as split_material
from ._surface import Surface as Surface
from ._surface import texel_samples as texel_samples
from ._visibility import Occluder as Occluder
from ._visibility import PackedMask as PackedMask
from ._visibility import camera_visibility as camera_visibility
from ._visibility import light_visibility as light_visibility
from ._visibility import primary_hits as primary_hits
