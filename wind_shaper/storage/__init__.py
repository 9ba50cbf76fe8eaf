"""What survives a crash: the sweep journal and the coordinator's run folder.

``journal``: every sweep sample appended to disk as it arrives (``SweepJournal``), read back by
``load_sweep_samples``. ``runstore``: the run folder (``RunStore``): each iteration's commands,
raw sweep, field and error, written atomically, so a restarted coordinator resumes.
"""
from .journal import SweepJournal, load_sweep_samples, read_rows
from .runstore import IterationData, RunFolderError, RunInfo, RunState, RunStore

__all__ = ['SweepJournal', 'load_sweep_samples', 'read_rows',
           'RunStore', 'RunInfo', 'RunState', 'IterationData', 'RunFolderError']
