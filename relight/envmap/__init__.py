"""Environment maps in the light-stage frame (x right, y up, z toward the main
camera): lat-long maps, per-pixel solid angles, rotation, and the light weights
that turn a map into a weighted sum of one-light-at-a-time images
(``relit = sum_l w_l * OLAT_l``, Debevec et al. 2000). See docs/relight_io.md."""

from ._bundled import bundled_envmap_path as bundled_envmap_path
from ._latlong import EnvMap as EnvMap
from ._latlong import direction_to_latlong as direction_to_latlong
from ._latlong import envmap_integral as envmap_integral
from ._latlong import envmap_irradiance as envmap_irradiance
from ._latlong import latlong_directions as latlong_directions
from ._latlong import latlong_solid_angles as latlong_solid_angles
from ._latlong import load_envmap as load_envmap
from ._latlong import rotate_envmap as rotate_envmap
from ._latlong import rotation_matrix as rotation_matrix
from ._latlong import sample_latlong as sample_latlong
from ._param import angular_directions as angular_directions
from ._param import angular_solid_angles as angular_solid_angles
from ._param import angular_to_latlong as angular_to_latlong
from ._param import cubemap_directions as cubemap_directions
from ._param import cubemap_solid_angles as cubemap_solid_angles
from ._param import cubemap_to_latlong as cubemap_to_latlong
from ._param import direction_to_angular as direction_to_angular
from ._param import direction_to_cubemap as direction_to_cubemap
from ._param import direction_to_mirrorball as direction_to_mirrorball
from ._param import latlong_to_angular as latlong_to_angular
from ._param import latlong_to_cubemap as latlong_to_cubemap
from ._param import latlong_to_mirrorball as latlong_to_mirrorball
from ._param import mirrorball_directions as mirrorball_directions
from ._param import mirrorball_solid_angles as mirrorball_solid_angles
from ._param import mirrorball_to_latlong as mirrorball_to_latlong
from ._param import sample_angular as sample_angular
from ._param import sample_cubemap as sample_cubemap
from ._param import sample_mirrorball as sample_mirrorball
from ._sampling import EnvSampler as EnvSampler
from ._sampling import envmap_pdf as envmap_pdf
from ._sampling import envmap_sampler as envmap_sampler
from ._sampling import sample_envmap as sample_envmap
from ._sh import sh_basis as sh_basis
from ._sh import sh_index as sh_index
from ._sh import sh_irradiance as sh_irradiance
from ._sh import sh_irradiance_kernel as sh_irradiance_kernel
from ._sh import sh_project as sh_project
from ._sh import sh_reconstruct as sh_reconstruct
from ._weights import barycentric_cell_integrals as barycentric_cell_integrals
from ._weights import light_weights as light_weights
from ._weights import light_weights_barycentric as light_weights_barycentric
from ._weights import rig_triangulation as rig_triangulation
from ._weights import rotation_sweep_weights as rotation_sweep_weights
from ._weights import voronoi_cell_integrals as voronoi_cell_integrals
