"""Where the sweeps of a recording are, and how force and pose are paired: pure logic, no ROS.

A recording holds continuous force (~1 kHz) and pose (~100 Hz) streams; the sweeps are the
intervals in which the coordinator reported ``state == 'sweeping'`` for an iteration k
(``IterationStatus``), or, in a recording without status messages, the intervals between
changes of the fan commands. Interval times are the bag's receive times [ns], one clock for
all topics; pairing inside an interval (``wind_shaper.estimation.align``) uses the messages' own
header stamps, as the field estimator does.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: The coordinator's state while the plate moves (IterationStatus.STATE_SWEEPING).
SWEEPING = 'sweeping'


@dataclass(frozen=True)
class StatusEvent:
    """One IterationStatus: receive time [ns], iteration k, state, fan order and commands."""

    t_ns: int
    iteration: int
    state: str
    fan_names: tuple[str, ...] = ()
    pwm: tuple[float, ...] = ()


@dataclass(frozen=True)
class CommandEvent:
    """One FanCommand: receive time [ns], fan names and PWM fractions."""

    t_ns: int
    fan_names: tuple[str, ...]
    pwm: tuple[float, ...]


@dataclass(frozen=True)
class Segment:
    """A sweep interval [start_ns, end_ns) of receive time, with its iteration (-1: unknown),
    fan order and commands in force [fraction]; complete is False when the recording ended
    (or the status stopped) before the sweep did."""

    start_ns: int
    end_ns: int
    iteration: int
    fan_names: tuple[str, ...]
    pwm: tuple[float, ...]
    complete: bool = True
    source: str = 'status'


def segments_from_status(events: Sequence[StatusEvent], end_ns: int,
                         commands: Sequence[CommandEvent] = ()) -> list[Segment]:
    """Sweep intervals from the coordinator's status: from the first 'sweeping' status of an
    iteration to the next status in another state (or of another iteration). A sweep still
    open at ``end_ns`` (end of the recording) is returned with complete=False. The commands are
    the status' ``pwm``; if a status carries none, the last FanCommand before the sweep."""
    out: list[Segment] = []
    current: StatusEvent | None = None
    for ev in sorted(events, key=lambda e: e.t_ns):
        sweeping = ev.state == SWEEPING
        if current is not None and (not sweeping or ev.iteration != current.iteration):
            out.append(_segment(current, ev.t_ns, True, commands))
            current = None
        if sweeping and current is None:
            current = ev
    if current is not None:
        out.append(_segment(current, end_ns + 1, False, commands))
    return out


def _segment(start: StatusEvent, end_ns: int, complete: bool, commands) -> Segment:
    names, pwm = start.fan_names, start.pwm
    if not pwm:
        before = [c for c in commands if c.t_ns <= start.t_ns]
        if before:
            names, pwm = before[-1].fan_names, before[-1].pwm
    return Segment(start.t_ns, end_ns, start.iteration, tuple(names), tuple(pwm), complete, 'status')


def segments_from_commands(commands: Sequence[CommandEvent], start_ns: int, end_ns: int,
                           tolerance: float = 1e-6) -> list[Segment]:
    """Intervals of constant fan commands: each change (a PWM differing by more than
    ``tolerance``, or other fan names) starts a segment that lasts until the next change or
    ``end_ns``. Re-publications of the same commands do not split. Without commands, the whole
    recording [start_ns, end_ns] is one segment with no commands."""
    out: list[Segment] = []
    last: CommandEvent | None = None
    for cmd in sorted(commands, key=lambda c: c.t_ns):
        if last is not None and _same(last, cmd, tolerance):
            continue
        if out:
            out[-1] = _close(out[-1], cmd.t_ns)
        out.append(Segment(cmd.t_ns, end_ns + 1, -1, tuple(cmd.fan_names), tuple(cmd.pwm),
                           True, 'commands'))
        last = cmd
    if not out:
        out.append(Segment(start_ns, end_ns + 1, -1, (), (), True, 'whole'))
    return out


def _same(a: CommandEvent, b: CommandEvent, tolerance: float) -> bool:
    return (tuple(a.fan_names) == tuple(b.fan_names) and len(a.pwm) == len(b.pwm)
            and bool(np.all(np.abs(np.subtract(a.pwm, b.pwm)) <= tolerance)))


def _close(seg: Segment, end_ns: int) -> Segment:
    return Segment(seg.start_ns, end_ns, seg.iteration, seg.fan_names, seg.pwm, seg.complete, seg.source)
