"""The coordinator's logic without ROS: a shaping run and its iteration state machine.

``iteration``: ``ShapingRun`` (run folder, prior, target, commands in force, history) and
``run_iteration`` (commanding -> sweeping -> estimating -> updating over ``RigPorts``).
``experiment``: ``Experiment`` (a checked design and its folder) and ``run_experiment`` (each
row: commanding -> sweeping -> checking -> stored or flagged, over the same ports).
``collect``: an experiment's feedback and answer. ``hold_point`` and ``held``: a held-plate
calibration point and the batch of them. ``sweeping``: where and how long a sweep goes, and when
it may end early. ``state``: the coordinator's bookkeeping (procedure running, commands in
force, status and diagnostics). ``requests``: the bounds of a request, and reading a model.
The coordinator node (``wind_shaper.nodes.coordinator``) only wires these to topics and services.
"""
from .experiment import (BIAS_MODES, CHECKING, Experiment, ExperimentPorts, RowResult, bias_plan,
                         run_experiment)
from .iteration import (CANCELLED, COMMANDING, DONE, ESTIMATING, FAILED, IDLE, PROGRESS, SWEEPING,
                        UPDATING, FanWatch, FieldAnswer, IterationStopped,
                        RigPorts, ShapingRun, past_iteration, run_iteration,
                        start_at_prior_optimum, tunnel_time)

__all__ = ['IDLE', 'COMMANDING', 'SWEEPING', 'ESTIMATING', 'UPDATING', 'DONE', 'FAILED',
           'CANCELLED', 'PROGRESS', 'IterationStopped', 'FieldAnswer', 'RigPorts', 'FanWatch',
           'ShapingRun', 'past_iteration', 'run_iteration', 'start_at_prior_optimum', 'tunnel_time',
           'CHECKING', 'Experiment',
           'ExperimentPorts', 'RowResult', 'run_experiment', 'BIAS_MODES', 'bias_plan']
