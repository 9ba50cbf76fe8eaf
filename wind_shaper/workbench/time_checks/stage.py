"""The time checks as a stage of the diagnosis, after ``case.open_case`` and before the
selection: every registered ``TimeCheck`` on the sweeps in recording order against the refitted
model (``Case.baseline``). Fills ``Case.time`` ({name: TimeResult}, registry order) and, when a
check found a fault and ``hold_on_time_fault`` is set, ``Case.held``: the stages that would
name effects are skipped (``Diagnosis.fit``) and the model stays as refitted.
"""
from __future__ import annotations

from .base import TIME_CHECKS, Recording

__all__ = ['check_time', 'time_text', 'faults', 'time_rows']


def check_time(case):
    """The stage (see the module docstring)."""
    s = case.settings
    case.time, case.held = {}, False
    if not s.check_time:
        return case
    rec = Recording.of(case.data, case.baseline.model, noise_sd=case.noise_sd,
                       material=s.material, z=s.time_z, enabled=case.geometry.fans.enabled)
    for name, check in TIME_CHECKS.items():
        case.time[name] = check.measure(rec, dict(case.time))
    if faults(case) and s.hold_on_time_fault:
        case.held = True
        case.final, case.final_rmse, case.final_raw = case.baseline, case.baseline_rmse, case.baseline_raw
    return case


def faults(case) -> list:
    """The time checks that found a fault, in registry order."""
    return [r for r in (getattr(case, 'time', None) or {}).values() if r.fault]


def time_text(case) -> str:
    """What the time checks found and what to do, in words ('' when nothing)."""
    found = faults(case)
    if not found:
        return ''
    repairs = list(dict.fromkeys(r.repair for r in found if r.repair))
    head = ('The sweeps depend on when they were recorded, not only on the commands and the '
            'place:')
    tail = (f' To diagnose these sweeps as they should have been recorded, give '
            f'{" and ".join(f"`{r}`" for r in repairs)}.' if repairs else '')
    return head + ''.join(f'\n- {r.message}' for r in found) + tail


def time_rows(case) -> list[list[str]]:
    """One row per time check for a report table: check, question, result, numbers."""
    return [[name, TIME_CHECKS[name].question if name in TIME_CHECKS else '', r.state,
             ', '.join(f'{k} {v:.3g}' if isinstance(v, float) else f'{k} {v}'
                       for k, v in r.numbers.items()) or r.message]
            for name, r in (case.time or {}).items()]
