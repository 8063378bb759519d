"""stage: the light stage as a simulator — rigs, cameras, meshes to surface
samples (texels or pixels), visibility, sensor model, polarisation and
gradient illumination, and one-light-at-a-time capture simulation. See
docs/stage.md."""

from ._camera import Camera as Camera, look_at as look_at
from ._camera import camera_ring as camera_ring, orthographic as orthographic
from ._camera import load_cameras as load_cameras, save_cameras as save_cameras
from ._capture import Capture as Capture
from ._gradient import PATTERNS as PATTERNS, diffuse_normals as diffuse_normals
from ._gradient import gradient_images as gradient_images, gradient_weights as gradient_weights
from ._gradient import specular_normals as specular_normals
from ._image import image_samples as image_samples
from ._mesh import HEAD_SCALE_MM as HEAD_SCALE_MM, Mesh as Mesh, head_mesh_path as head_mesh_path
from ._mesh import MeshReport as MeshReport, check_mesh as check_mesh
from ._mesh import load_head as load_head, load_mesh as load_mesh
from ._rig import Gonioreflectometer as Gonioreflectometer, gonioreflectometer as gonioreflectometer
from ._rig import Rig as Rig, geodesic_dome as geodesic_dome, light_stage_x as light_stage_x
from ._rig import calibrate as calibrate, directional_rig as directional_rig, fibonacci_sphere as fibonacci_sphere
from ._rig import light_stage_x_faces as light_stage_x_faces
from ._rig import make_rig as make_rig, voronoi_solid_angles as voronoi_solid_angles
from ._sensor import Sensor as Sensor, sense as sense
from ._simulate import DEPOLARIZED_TRANSMISSION as DEPOLARIZED_TRANSMISSION
from ._simulate import Subsurface as Subsurface, split_material as split_material
from ._simulate import shading_directions as shading_directions, simulate as simulate
from ._simulate import simulate_chunks as simulate_chunks
from ._surface import Surface as Surface, texel_samples as texel_samples
from ._visibility import PackedMask as PackedMask
from ._visibility import camera_visibility as camera_visibility, light_visibility as light_visibility
from ._visibility import primary_hits as primary_hits
