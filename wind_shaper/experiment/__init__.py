"""Designed experiments: the fan commands of a set of sweeps, made and checked before any fan sees
them (``design``). The coordinator runs a design through the node graph
(``wind_shaper.coordination.experiment``), the sweeps are stored in an experiment folder
(``wind_shaper.storage.experiments``) that the workbench reads. Pure Python: no rclpy.
"""
from .design import Design, DesignError, check_design, design_commands, make_design, write_design

__all__ = ['Design', 'DesignError', 'check_design', 'design_commands', 'make_design', 'write_design']
