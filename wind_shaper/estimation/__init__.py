"""Field estimation: from force and pose streams to the force field at the key points.

``align``: force (about 1 kHz) and pose (about 100 Hz) streams -> time-aligned sweep pairs.
``frames``: rigid transforms, quaternions and the mocap relay's plate-centre gate.
``coverage``: the key points a moving plate has passed (live feedback, the re-sweep flag).
``field``: GET_CLOSEST subsampling and the Gaussian-process field (mean and std at any point).
``turbulent``: the GP whose noise grows with the force and comes in gusts over sample time, its
hyperparameters fitted per sweep (the default estimator's model: a std that can be trusted);
``local_turbulent``: the same model solved tile by tile for walls too large for one GP.
Positions [m, tunnel frame], forces [N], times [s].
"""
import importlib

# Each name is imported from its module when first used: a node that needs the mocap relay's
# frames or a field message's type does not load SciPy's spatial and optimisation packages with
# the GP (0.4-0.6 s of CPU at every start of such a node, bench/node_start.py).
_MODULE_OF = {
    **dict.fromkeys(('Coverage', 'coverage_share'), 'coverage'),
    **dict.fromkeys(('MIN_OVERLAP', 'SampleBuffer', 'align_sweep', 'pose_period'), 'align'),
    **dict.fromkeys(('FieldEstimate', 'FieldEstimator', 'GaussianProcessField',
                     'LocalGaussianProcessField', 'Subsample', 'closest_samples',
                     'fit_hyperparameters', 'get_closest'), 'field'),
    'LocalTurbulentGaussianProcessField': 'local_turbulent',
    **dict.fromkeys(('TURBULENCE_BOUNDS', 'TurbulenceParameters', 'TurbulentGaussianProcessField',
                     'fit_turbulence'), 'turbulent'),
    **dict.fromkeys(('PlateRelay', 'RelayResult', 'RelayStats', 'RigidTransform', 'Verdict',
                     'quat_conjugate', 'quat_from_yaw', 'quat_multiply', 'quat_normalize',
                     'quat_rotate', 'quat_to_matrix', 'quat_to_yaw'), 'frames'),
}

__all__ = list(_MODULE_OF)


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'.{module}', __name__), name)
    globals()[name] = value   # found directly from now on
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
