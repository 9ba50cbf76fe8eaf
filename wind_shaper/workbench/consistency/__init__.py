"""Does a candidate effect hold where it should? The measurements behind the checks a finding
must pass before it is named (``wind_shaper.workbench.checks``), one module per question:

* ``sweeps``: one value across sweeps, whatever the commands (``check_across_sweeps``), and the
  rule that judges a spread of values (``judge_spread``);
* ``beside``: the same beside a discrepancy model of what the library lacks
  (``check_beside_discrepancy``);
* ``halves``: one value on both sides of the footprint and at every load (``check_across_space``,
  ``check_across_load``);
* ``within_range``: fitted parameters inside the range their physics allows
  (``check_within_range``).

Forces [N], positions [m].
"""
from .beside import BesideCheck, check_beside_discrepancy, gain_beside_discrepancy
from .halves import across_load, across_space, check_across_load, check_across_space
from .sweeps import SweepCheck, check_across_sweeps, judge_spread
from .within_range import check_within_range, within_range

__all__ = ['SweepCheck', 'BesideCheck', 'check_across_sweeps', 'check_beside_discrepancy',
           'check_across_space', 'check_across_load', 'check_within_range', 'judge_spread',
           'gain_beside_discrepancy', 'across_space', 'across_load', 'within_range']
