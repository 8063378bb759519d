"""relight.demo: ``relight demo`` as one library call.

* :func:`run_demo`: the bundled head scan with its own skin textures and spatially varying subsurface
  scattering, simulated under the Light Stage X, fitted (the model ladder with normals, then subsurface),
  relit under an environment map with the same renderer as its truth, and reported against that truth;
  returns a :class:`Demo` that writes its folder (``Demo.write``) and gives the viewer's sweep
  (``Demo.sweeps``).

It sits above every other library room (it uses simulation, fitting, render and view), below the CLI.
"""

from ._demo import Demo as Demo
from ._demo import run_demo as run_demo

__all__ = ["Demo", "run_demo"]
