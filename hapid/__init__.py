"""hapid: differentiable system identification of multi-DOF haptic interfaces (JAX).

Importing hapid switches on float64 (``jax_enable_x64``).
"""

from . import _config  # noqa: F401  (float64 before anything else)
from . import control as control
from . import device as device
from . import experiment as experiment
from . import fit as fit
from . import uncertainty as uncertainty
from .frf import FRF as FRF
from .frf import as_frf as as_frf
from .impedance import ImpedanceModel as ImpedanceModel
from .impedance import SecondOrder as SecondOrder
from .impedance import plant as plant
from .impedance import singular_values as singular_values
from .impedance import span_db as span_db

__version__ = "0.1.0"
