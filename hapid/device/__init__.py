"""Simulated n-rod haptic interfaces: geometry, hand, mechanism chain, extra modes, presets."""

from ..lti import StateSpace as StateSpace
from ..lti import zoh as zoh
from ._device import Device as Device
from ._device import ParallelDevice as ParallelDevice
from ._device import SecondOrderDevice as SecondOrderDevice
from ._geometry import Geometry as Geometry
from ._geometry import Pose as Pose
from ._geometry import cu5_geometry as cu5_geometry
from ._geometry import hexapod_geometry as hexapod_geometry
from ._geometry import quad_geometry as quad_geometry
from ._geometry import tripod_geometry as tripod_geometry
from ._parts import ExtraModes as ExtraModes
from ._parts import Hand as Hand
from ._parts import Mechanism as Mechanism
from ._parts import default_modes as default_modes
from ._parts import no_modes as no_modes
from ._parts import nominal_hand as nominal_hand
from ._parts import nominal_mechanism as nominal_mechanism
from ._parts import virtual_subject as virtual_subject
from ._presets import PRESETS as PRESETS
from ._presets import cu5 as cu5
from ._presets import cu5_soft as cu5_soft
from ._presets import hexapod6 as hexapod6
from ._presets import preset as preset
from ._presets import quad4 as quad4
from ._presets import tripod3 as tripod3
