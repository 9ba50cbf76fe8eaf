"""The checks a candidate effect must pass before it is named, as small registered objects.

Each check answers one question (``Check.question``), measures numbers and writes its refusal
in words (``CheckResult``); ``CHECKS`` holds them by name in the order they run. The guard
judges every candidate the selection tries; the others judge the effects the selection added
(``check_findings``, the diagnosis's stage after the selection): first the check across sweeps
(with its second chance beside a discrepancy model), then one after another the checks that can
refuse a finding that holds across sweeps.

A new check is one new module here (a ``Check`` subclass decorated with ``register_check``)
and one import line below, in the place it should run.
"""
from .base import CHECKS, Check, CheckResult, Round, register_check

# the checks, in the order they run: one line each
from . import guard  # noqa: E402,F401
from . import across_sweeps  # noqa: E402,F401
from . import beside_discrepancy  # noqa: E402,F401
from . import within_range  # noqa: E402,F401
from . import specific  # noqa: E402,F401
from . import both_sides  # noqa: E402,F401
from . import every_load  # noqa: E402,F401
from . import thrust_curves  # noqa: E402,F401

from .run import check_findings  # noqa: E402

__all__ = ['CHECKS', 'Check', 'CheckResult', 'Round', 'register_check', 'check_findings']
