"""What survives a crash: the sweep journal and the coordinator's run folder.

``journal``: every sweep sample appended to disk as it arrives (``SweepJournal``), read back by
``load_sweep_samples``. ``runstore``: the run folder (``RunStore``): each iteration's commands,
raw sweep, field and error, written atomically, so a restarted coordinator resumes.
``experiments``: the experiment folder (``ExperimentStore``): the stored sweeps of a designed
experiment, row by row, and the takes flagged for a re-sweep. ``held``: a held-plate calibration
batch point by point (``HeldBatch``), so a guided batch resumes.
"""
from .experiments import (FLAGGED, PENDING, STORED, ExperimentPlan, ExperimentStore,
                          StoredSweep)
from .held import RECORDED, SKIPPED, HeldBatch
from .journal import SweepJournal, load_sweep_samples, read_rows
from .runstore import IterationData, RunFolderError, RunInfo, RunState, RunStore

__all__ = ['ExperimentStore', 'ExperimentPlan', 'StoredSweep', 'STORED', 'FLAGGED', 'PENDING',
           'HeldBatch', 'RECORDED', 'SKIPPED', 'SweepJournal', 'load_sweep_samples', 'read_rows',
           'RunStore', 'RunInfo', 'RunState', 'IterationData', 'RunFolderError']
