"""Multisine experiments on simulated devices and empirical FRF estimation."""

from ._estimate import estimate_frf as estimate_frf
from ._estimate import estimate_frf_h1 as estimate_frf_h1
from ._excitation import Multisine as Multisine
from ._excitation import check_on_grid as check_on_grid
from ._excitation import check_patterns as check_patterns
from ._excitation import multisine as multisine
from ._excitation import paper_frequencies as paper_frequencies
from ._excitation import patterns as patterns
from ._excitation import schroeder_phases as schroeder_phases
from ._fast import simulate_frf as simulate_frf
from ._impedance import RESPONSE_KINDS as RESPONSE_KINDS
from ._impedance import EstimateStatus as EstimateStatus
from ._impedance import EstimateUndecided as EstimateUndecided
from ._impedance import ImpedanceEstimate as ImpedanceEstimate
from ._impedance import TimeSeries as TimeSeries
from ._impedance import estimate_impedance as estimate_impedance
from ._impedance import estimate_impedance_h1 as estimate_impedance_h1
from ._protocol import Protocol as Protocol
from ._protocol import Run as Run
from ._protocol import validate_run as validate_run
from ._synthesis import Response as Response
from ._synthesis import periodic_run as periodic_run
from ._synthesis import time_domain_response as time_domain_response
from ._synthesis import time_domain_run as time_domain_run
from ._transient import low_coherence_note as low_coherence_note
