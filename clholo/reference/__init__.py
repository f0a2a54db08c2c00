"""NumPy reference of everything clholo computes on the device: the spec in code.

Plain, readable, complex128/float64. Every OpenCL kernel is tested against a function here, and
the functions follow ``docs/conventions.md`` (the project's copy of HOLOGRAPHY.md) line by line:

* FFTs are NumPy's (unnormalised forward, ``1/N`` inverse, unshifted ``fftfreq`` order).
* Angular spectrum propagation by ``dz`` metres (positive = towards the viewer, +z) with the
  band limit of Matsushima & Shimobaba (2009) and zero padding.
* Random phases from Philox4x32-10, keyed by the seed and indexed by (frame, colour, layer,
  pixel), converted to float32 exactly as the kernels do.
* The MPI recursion of the paper: back to front, ``v = sqrt(1-a) u + sqrt(c a) exp(1j phi)``,
  then propagate to the next nearer plane, the last step landing on the hologram plane z = 0.

The core (FFT, propagation, phases, the MPI recursion) lives in :mod:`clholo.reference.core`; each
further kernel family keeps its reference in a submodule of the same name as its kernel file
(``clholo.reference.views`` for ``kernels/views.cl``, ...). This package re-exports them all, so
that ``clholo.reference.<name>`` reaches every reference function.
"""

from .core import *  # noqa: F401,F403
from .core import (PHILOX_M0, PHILOX_M1, PHILOX_W0, PHILOX_W1, TWO_PI_F32, Pad,  # noqa: F401
                   layer_steps, phase_from_word, seed_key)
from .encode import *  # noqa: F401,F403
from .rpws import *  # noqa: F401,F403
from .views import *  # noqa: F401,F403
from .baselines import *  # noqa: F401,F403
from .rayoptics import *  # noqa: F401,F403
from .quantize import *  # noqa: F401,F403
