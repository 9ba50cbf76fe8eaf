"""The simulated tunnel: a pure numpy/scipy plant behind the ``Tunnel`` protocol.

``SimulatedTunnel`` is deliberately not the project's prior model (flat-topped jets, cubic thrust
curves, a central-fan ring, fixed build imperfections, plate averaging, turbulence), and can carry
any subset of switchable ``HIDDEN_EFFECTS`` whose true parameters tests and benchmarks can check
a diagnosis against. No ROS here.

``SimAutopilot`` (MAVLink) and ``SimNetFtServer`` (ATI Net F/T RDT) put the plant behind the
rig's own protocols on UDP loopback; they load on first use, so the plant alone never imports
pymavlink.
"""
from .effects import (HIDDEN_EFFECTS, BackgroundDraft, DeadBand, ElongatedFootprint, HiddenEffect,
                      JetInteraction, Swirl, TiltedFan, WallBoundaryLayer, WeakFan,
                      effects_from_config, make_effect, register_effects)
from .coupled_effects import (CoflowCarry, DiffuserSeparation, EscCurrentLimit, FlowScreen, JetConfinement,
                              JetPairing, RecirculationCore, SideInlet, StallDip, SupplySag)
from .errors import CommandError, EffectError
from .noise import NoiseModel
from .paths import RandomWalkPath, TourPath, path_from_config
from .physics import BUILD_SEED, Imperfections, PlantConstants, ThrustCurve
from .plant import PlantState, SimulatedTunnel
from .unmodelled_effects import (OTHER_FORM, OUTSIDE_FRESH, OUTSIDE_LIBRARY, OUTSIDE_SECOND,
                                 OUTSIDE_THIRD, TIME_FAULTS, CeilingDownwash, CoandaAttachment,
                                 DragLaw, EscCrosstalk, HoneycombBlockage, HubShadow, MocapLatency,
                                 JetDeflection, JetSpreading, NeighbourStarvation, PlenumStarvation,
                                 QuadraticSwirl, SensorZeroDrift, SideDraft, StandWake,
                                 ThermalGradient, UnsettledFans, VaneRipple, WallLeak,
                                 WallReflection, WallReturnFlow)

__all__ = [
    'SimulatedTunnel', 'PlantState', 'PlantConstants', 'ThrustCurve', 'Imperfections', 'BUILD_SEED',
    'NoiseModel', 'TourPath', 'RandomWalkPath', 'path_from_config',
    'HiddenEffect', 'WeakFan', 'Swirl', 'WallBoundaryLayer', 'JetInteraction', 'DeadBand',
    'TiltedFan', 'ElongatedFootprint', 'BackgroundDraft', 'HIDDEN_EFFECTS', 'make_effect',
    'HoneycombBlockage', 'StandWake', 'PlenumStarvation', 'SideDraft', 'QuadraticSwirl',
    'ThermalGradient', 'JetDeflection', 'EscCrosstalk', 'WallReturnFlow', 'VaneRipple',
    'JetSpreading', 'HubShadow', 'NeighbourStarvation', 'CoandaAttachment', 'WallLeak',
    'DragLaw', 'MocapLatency', 'CeilingDownwash', 'WallReflection', 'SupplySag',
    'RecirculationCore', 'JetPairing', 'StallDip', 'CoflowCarry', 'EscCurrentLimit', 'DiffuserSeparation', 'SideInlet', 'JetConfinement',
    'FlowScreen', 'SensorZeroDrift', 'UnsettledFans', 'TIME_FAULTS',
    'OUTSIDE_LIBRARY', 'OUTSIDE_FRESH', 'OUTSIDE_SECOND', 'OUTSIDE_THIRD', 'OTHER_FORM',
    'effects_from_config', 'register_effects', 'EffectError', 'CommandError',
    'SimAutopilot', 'SimNetFtServer', 'NetFtFaults',
]

_LAZY = {'SimAutopilot': '.autopilot', 'SimNetFtServer': '.netft_server', 'NetFtFaults': '.netft_server'}


def __getattr__(name):
    if name in _LAZY:
        from importlib import import_module
        return getattr(import_module(_LAZY[name], __name__), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
