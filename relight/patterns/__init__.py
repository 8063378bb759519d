"""Learned lighting patterns (Kang et al. 2018, "Efficient Reflectance Capture
Using an Autoencoder", SIGGRAPH): lumitexels simulated through stage's forward
model, the pattern autoencoder (a [0, 1]-bounded linear pattern layer, the
sensor's per-frame noise, decoders to the material and the lumitexel),
training with optax, and the fit path from pattern captures (decoder start,
then least squares on the pattern measurements). See docs/patterns.md."""

from ._autoencoder import ALPHA_DECODE_MAX as ALPHA_DECODE_MAX
from ._autoencoder import ALPHA_DECODE_MIN as ALPHA_DECODE_MIN
from ._autoencoder import PatternAutoencoder as PatternAutoencoder
from ._autoencoder import grid_features as grid_features
from ._autoencoder import lumitexel_target as lumitexel_target
from ._autoencoder import measure as measure
from ._autoencoder import sensor_noise as sensor_noise
from ._fit import decoder_start as decoder_start
from ._fit import fit_learned as fit_learned
from ._lumitexels import ALPHA_GRID as ALPHA_GRID
from ._lumitexels import TEST_RANGES as TEST_RANGES
from ._lumitexels import TRAIN_RANGES as TRAIN_RANGES
from ._lumitexels import Lumitexels as Lumitexels
from ._lumitexels import ParameterRanges as ParameterRanges
from ._lumitexels import as_capture as as_capture
from ._lumitexels import as_surface as as_surface
from ._lumitexels import geometry_features as geometry_features
from ._lumitexels import lumitexels as lumitexels
from ._lumitexels import sample_geometry as sample_geometry
from ._lumitexels import sample_materials as sample_materials
from ._lumitexels import simulate_lumitexels as simulate_lumitexels
from ._lumitexels import specular_bases as specular_bases
from ._train import TrainConfig as TrainConfig
from ._train import load_model as load_model
from ._train import loss_terms as loss_terms
from ._train import make_optimizer as make_optimizer
from ._train import save_model as save_model
from ._train import total_loss as total_loss
from ._train import train as train
