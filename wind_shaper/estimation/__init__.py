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
from .coverage import Coverage, coverage_share
from .align import MIN_OVERLAP, SampleBuffer, align_sweep, pose_period
from .field import (FieldEstimate, FieldEstimator, GaussianProcessField, LocalGaussianProcessField,
                    Subsample, closest_samples, fit_hyperparameters, get_closest)
from .local_turbulent import LocalTurbulentGaussianProcessField
from .turbulent import (TURBULENCE_BOUNDS, TurbulenceParameters, TurbulentGaussianProcessField,
                        fit_turbulence)
from .frames import (PlateRelay, RelayResult, RelayStats, RigidTransform, Verdict, quat_conjugate,
                     quat_from_yaw, quat_multiply, quat_normalize, quat_rotate, quat_to_matrix,
                     quat_to_yaw)

__all__ = [
    'Coverage', 'coverage_share', 'align_sweep', 'pose_period', 'SampleBuffer', 'MIN_OVERLAP',
    'FieldEstimate', 'FieldEstimator', 'GaussianProcessField', 'LocalGaussianProcessField',
    'Subsample', 'closest_samples', 'get_closest', 'fit_hyperparameters',
    'TURBULENCE_BOUNDS', 'TurbulenceParameters', 'TurbulentGaussianProcessField', 'fit_turbulence',
    'LocalTurbulentGaussianProcessField',
    'RigidTransform', 'PlateRelay', 'RelayResult', 'RelayStats', 'Verdict', 'quat_normalize',
    'quat_multiply', 'quat_conjugate', 'quat_to_matrix', 'quat_rotate', 'quat_to_yaw',
    'quat_from_yaw',
]
