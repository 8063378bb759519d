"""stage: the light stage as a simulator — rigs, cameras, meshes to surface
samples, visibility, and one-light-at-a-time capture simulation."""

from ._camera import Camera as Camera, look_at as look_at
from ._capture import Capture as Capture
from ._mesh import HEAD_SCALE_MM as HEAD_SCALE_MM, Mesh as Mesh, head_mesh_path as head_mesh_path
from ._mesh import load_head as load_head, load_mesh as load_mesh
from ._rig import Rig as Rig, geodesic_dome as geodesic_dome, light_stage_x as light_stage_x
from ._rig import make_rig as make_rig, voronoi_solid_angles as voronoi_solid_angles
from ._simulate import shading_directions as shading_directions, simulate as simulate
from ._surface import Surface as Surface, texel_samples as texel_samples
from ._visibility import camera_visibility as camera_visibility, light_visibility as light_visibility
from ._visibility import primary_hits as primary_hits
