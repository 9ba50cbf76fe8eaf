"""The shaping loop (``loop``), its update rules (``update``: the interface and Algorithm 1;
``adaptive``, built on ``basis``, ``shape_fit``, ``secant``, ``qp``, ``stopping``) and their
settings from shaping.yaml (``settings``); targets (``profiles``, ``expression``, ``csv_profile``;
``targets`` has ``make_target``) and whether the fans can reach them (``reach``).
"""
from .adaptive import AdaptiveUpdate
from .basis import FanBasis
from .csv_profile import CsvTarget, write_template_csv
from .expression import ExpressionTarget
from .loop import IterationRecord, ShapingLoop, mean_squared_error
from .profiles import GaussianTarget, ParabolicTarget, Target, UniformTarget
from .qp import box_qp
from .reach import Reach, check_reachable, model_reach
from .secant import SecantCorrection, broyden_update
from .settings import ShapingConfig, load_shaping
from .shape_fit import ShapeFit
from .stopping import StoppingRule
from .targets import TARGET_KINDS, make_target
from .update import CommandBounds, PaperUpdate, PastIteration, UpdateInput, UpdateRule, UpdateStep

__all__ = [
    # the loop and its settings
    'ShapingLoop', 'IterationRecord', 'mean_squared_error', 'ShapingConfig', 'load_shaping',
    # update rules
    'UpdateRule', 'UpdateInput', 'UpdateStep', 'PastIteration', 'CommandBounds', 'PaperUpdate',
    'AdaptiveUpdate', 'StoppingRule', 'ShapeFit', 'FanBasis', 'box_qp', 'SecantCorrection',
    'broyden_update',
    # targets and whether the fans can reach them
    'Target', 'UniformTarget', 'GaussianTarget', 'ParabolicTarget', 'ExpressionTarget',
    'CsvTarget', 'make_target', 'TARGET_KINDS', 'write_template_csv',
    'Reach', 'model_reach', 'check_reachable',
]
