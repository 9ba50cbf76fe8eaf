"""The model workbench: compare the model with sweeps, see where it fails, find the physical
effect it misses, add it, and watch the error fall.

* data sets of sweeps (``SweepSet``; from the simulator, bags, run folders, shape reports),
  split by sweep;
* fitting with uncertainties (``fit_model``), scores and the held-out model error (``HeldOut``);
* where the model fails (``analyse_residuals``);
* the candidate-effect library (``Library``; terms in ``wind_shaper.model``) and the
  diagnosis (``Diagnosis``: screening, refits, forward selection, a guard against spurious
  findings, the registered checks an effect must pass before it is named (``checks``), findings
  in plain words);
* the commissioned reference model (``commission``) the diagnosis measures changes against;
* the closed loop on the simulator (``compare_closed_loop``) and reports (``Report``).

Pure Python (numpy, scipy, matplotlib): no rclpy. See docs/workbench.md.
"""
from .closed_loop import LoopComparison, compare_closed_loop
from .data import (FitData, SweepSet, design_commands, from_bag, from_report, from_run_folder,
                   from_sim, load_sweeps)
from .checks import CHECKS, Check, CheckResult, register_check
from .consistency import SweepCheck, check_across_sweeps
from .diagnose import Diagnosis, Trial, fit_mask
from .errors import CandidateError, DataSourceError, FitError, WorkbenchError
from .fitting import FitResult, Frozen, fit_model, jackknife_std
from .library import Candidate, Library, apply_candidate, candidate_for_hidden_effect, default_library
from .metrics import HeldOut, Scores, evaluate, scores
from .reference import COMMISSIONING_PLAN, Reference, commission, commission_on, with_build
from .residuals import ResidualAnalysis, analyse_residuals

__all__ = [
    'SweepCheck', 'check_across_sweeps', 'CHECKS', 'Check', 'CheckResult', 'register_check',
    'SweepSet', 'FitData', 'design_commands', 'from_sim', 'from_bag', 'from_run_folder', 'from_report',
    'load_sweeps', 'fit_model', 'FitResult', 'Frozen', 'jackknife_std', 'HeldOut', 'Scores', 'scores',
    'evaluate', 'analyse_residuals', 'ResidualAnalysis', 'Candidate', 'Library', 'default_library',
    'apply_candidate', 'candidate_for_hidden_effect', 'Diagnosis', 'Trial', 'fit_mask', 'Reference',
    'commission', 'commission_on', 'with_build', 'COMMISSIONING_PLAN', 'compare_closed_loop',
    'LoopComparison', 'WorkbenchError', 'DataSourceError', 'FitError', 'CandidateError',
]
