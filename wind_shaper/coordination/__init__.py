"""The coordinator's logic without ROS: a shaping run and its iteration state machine.

``iteration``: ``ShapingRun`` (run folder, prior, target, commands in force, history) and
``run_iteration`` (commanding -> sweeping -> estimating -> updating over ``RigPorts``). The
coordinator node (``wind_shaper.nodes.coordinator``) only wires these to topics and services.
"""
from .iteration import (CANCELLED, COMMANDING, DONE, ESTIMATING, FAILED, IDLE, PROGRESS, SWEEPING,
                        UPDATING, FanWatch, FieldAnswer, IterationStopped,
                        RigPorts, ShapingRun, past_iteration, run_iteration)

__all__ = ['IDLE', 'COMMANDING', 'SWEEPING', 'ESTIMATING', 'UPDATING', 'DONE', 'FAILED',
           'CANCELLED', 'PROGRESS', 'IterationStopped', 'FieldAnswer', 'RigPorts', 'FanWatch',
           'ShapingRun', 'past_iteration', 'run_iteration']
