"""The simulated tunnel: a pure numpy/scipy plant behind the ``Tunnel`` protocol.

``SimulatedTunnel`` is deliberately not the project's prior model (flat-topped jets, cubic thrust
curves, a central-fan ring, fixed build imperfections, plate averaging, turbulence), and can carry
any subset of switchable ``HIDDEN_EFFECTS`` whose true parameters tests and benchmarks can check
a diagnosis against. No ROS here.
"""
from .effects import (HIDDEN_EFFECTS, BackgroundDraft, DeadBand, ElongatedFootprint, HiddenEffect,
                      JetInteraction, Swirl, TiltedFan, WallBoundaryLayer, WeakFan,
                      effects_from_config, make_effect)
from .errors import CommandError, EffectError
from .noise import NoiseModel
from .paths import RandomWalkPath, TourPath, path_from_config
from .physics import BUILD_SEED, Imperfections, PlantConstants, ThrustCurve
from .plant import PlantState, SimulatedTunnel

__all__ = [
    'SimulatedTunnel', 'PlantState', 'PlantConstants', 'ThrustCurve', 'Imperfections', 'BUILD_SEED',
    'NoiseModel', 'TourPath', 'RandomWalkPath', 'path_from_config',
    'HiddenEffect', 'WeakFan', 'Swirl', 'WallBoundaryLayer', 'JetInteraction', 'DeadBand',
    'TiltedFan', 'ElongatedFootprint', 'BackgroundDraft', 'HIDDEN_EFFECTS', 'make_effect',
    'effects_from_config', 'EffectError', 'CommandError',
]
