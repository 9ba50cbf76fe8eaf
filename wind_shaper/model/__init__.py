"""The tunnel's force model Phi(U, z) [N]: ``terms`` (the composable-term machinery and the
``TERMS`` registry), ``prior`` (the paper's FanJets + CentralRing), ``fanwise`` (the fan-resolved
protocol, tree helpers, Wrapper), ``fan_effects``, ``footprint_effects``, ``flow_effects`` and ``swirl_forms`` (the candidate effects),
``modelfile`` (save/load), ``plugins`` (user terms) and ``calibration`` (batch and fit).

Import from here (``from wind_shaper.model import FanGain``): every module is imported below, so
every term kind is registered as soon as anything of the package is used.
"""
from .terms import (TERMS, Hyper, Product, Sum, Term, finite_difference_jacobian, register_term,
                    term_from_dict)
from .prior import POLY_BOUNDS, SIGMA_BOUNDS, CentralRing, FanJets, paper_prior
from .fanwise import (PLATE_SIDE, Wrapper, fan_landing, fan_part, fan_part_batched, fan_thrust,
                      fan_thrust_batched, fan_width, find_term, has_fan_parts, is_fan_sum,
                      param_slices, refix, set_fixed, term_label, walk, wrap)
from .fan_effects import ALL_FANS, FanCurve, FanGain, FanPush, FanShift, FanWrapper, sweep_prior
from .footprint_effects import FanElongation, FanShape, FanWidth
from .flow_effects import (Background, DeadBand, JetInteraction, JetInteractionPower, Swirl,
                           SwirlQuadratic, WallLayer)
from .swirl_forms import SWIRL_LAWS, SwirlFollows
from .discrepancy import MODE_NAMES, CommandScale, Discrepancy, FieldFormula, command_features, feature_words
from .modelfile import FORMAT_VERSION, load_model, model_error, model_from_text, save_model
from .plugins import ENV_VAR, HOW_TO_LOAD, env_plugins, load_plugin, load_plugins, plugin_families
from .calibration import CalibrationPlan, ModelFit, collect_calibration, fit_model

__all__ = [
    # terms: the composable-term machinery and the registry of kinds
    'Term', 'Hyper', 'Sum', 'Product', 'TERMS', 'register_term', 'term_from_dict',
    'finite_difference_jacobian',
    # prior: the paper's coarse prior
    'FanJets', 'CentralRing', 'paper_prior', 'sweep_prior', 'POLY_BOUNDS', 'SIGMA_BOUNDS',
    # fanwise: the fan-resolved protocol, tree helpers, the wrapper base
    'Wrapper', 'wrap', 'fan_part', 'fan_thrust', 'fan_width', 'fan_landing', 'is_fan_sum',
    'has_fan_parts', 'fan_part_batched', 'fan_thrust_batched', 'walk', 'param_slices', 'find_term',
    'term_label', 'refix', 'set_fixed', 'PLATE_SIDE',
    # fan_effects, footprint_effects: per-fan candidate effects
    'FanWrapper', 'ALL_FANS', 'FanGain', 'FanShift', 'FanPush', 'FanWidth', 'FanElongation', 'FanCurve', 'FanShape',
    # flow_effects: whole-flow candidate effects
    'Swirl', 'SwirlQuadratic', 'JetInteraction', 'JetInteractionPower', 'DeadBand', 'Background',
    'WallLayer',
    # swirl_forms: other laws of the swirl family's angle
    'SwirlFollows', 'SWIRL_LAWS',
    # discrepancy: what the library does not explain, without physics
    'Discrepancy', 'FieldFormula', 'CommandScale', 'command_features', 'feature_words', 'MODE_NAMES',
    # modelfile: model files
    'save_model', 'load_model', 'model_error', 'model_from_text', 'FORMAT_VERSION',
    # plugins: user terms, families and simulator effects
    'load_plugins', 'load_plugin', 'env_plugins', 'plugin_families', 'ENV_VAR', 'HOW_TO_LOAD',
    # calibration: the paper's calibration batch and its fit
    'CalibrationPlan', 'collect_calibration', 'fit_model', 'ModelFit',
]
