"""Bounds on everything that crosses a process boundary, in one place (``Limits``).

A service request, a model file, a design or a run folder is checked against these bounds
before it is parsed: strings and arrays by length, YAML by size, depth and anchors
(``wind_shaper.core.safe_yaml``), a designed experiment by its plate time. A refusal raises
``LimitError``, which says which bound, the size found, and what to do, and quotes at most
``EXCERPT_CHARS`` characters of what it refused (``excerpt``).

The nodes that take requests declare every field as a ROS parameter ``limits.<name>``
(``wind_shaper.ros.params``; the shipped values in config/coordinator.yaml and
config/field_estimator.yaml); files read by the CLI and the nodes alike use ``DEFAULT_LIMITS``.
Units: bytes, characters, counts, seconds [s].
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Sized

from .errors import LimitError

#: The most characters of a refused input an error message quotes.
EXCERPT_CHARS = 60


def _bound(default, description: str, low, high):
    """A Limits field that nodes declare as a read-only ROS parameter (the metadata
    ``wind_shaper.ros.params.param`` writes; the core imports nothing of ROS)."""
    meta = {'description': description, 'low': low, 'high': high, 'read_only': True,
            'array_of': None}
    return field(default=default, metadata={'ros': meta})


@dataclass(frozen=True)
class Limits:
    """The bounds; see the module docstring. Every count is inclusive (the largest accepted)."""

    yaml_bytes: int = _bound(1_048_576, 'largest YAML text read: a model file (also sent as '
                             'set_model text), a design, a run or experiment description, a '
                             'config file [bytes]', 1024, 1 << 30)
    yaml_depth: int = _bound(40, 'deepest nesting of mappings and lists in any YAML read '
                             '(anchors and aliases are always refused)', 4, 1000)
    text_chars: int = _bound(1000, 'longest free text in a request: a target spec, an expression, '
                             'a path, a design source [characters]', 64, 1_000_000)
    name_chars: int = _bound(200, 'longest name in a request: a fan name, an experiment name, a '
                             'row label [characters]', 16, 10_000)
    fans: int = _bound(64, 'most fans (fan names, commands per row) a request may name', 1,
                       100_000)
    design_rows: int = _bound(1000, 'most sweeps a designed experiment (collect) may have', 1,
                              10_000_000)
    plate_budget_s: float = _bound(43200.0, 'most plate time a designed experiment may plan: '
                                   'sweeps x (sweep length + settle) [s]', 1.0, 1e9)
    query_points: int = _bound(20_000, 'most positions one field query may ask for', 1,
                               100_000_000)
    file_bytes: int = _bound(64 * 1_048_576, 'largest other text file read whole (a design CSV, a '
                             'target CSV, a JSON record) [bytes]', 1024, 1 << 40)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            meta = f.metadata['ros']
            if not meta['low'] <= value <= meta['high']:
                raise LimitError(f'limits.{f.name} = {value!r} lies outside '
                                 f'[{meta["low"]}, {meta["high"]}]: {meta["description"]}')

    # -- checks ------------------------------------------------------------------------------------------
    def text(self, value: str, what: str, *, name: bool = False) -> str:
        """``value`` when it has at most text_chars (name: name_chars) characters."""
        bound, key = (self.name_chars, 'name_chars') if name else (self.text_chars, 'text_chars')
        if len(value) > bound:
            raise LimitError(f'{what} has {len(value)} characters, more than the {bound} allowed '
                             f'(limits.{key}): {excerpt(value)}; send a shorter one')
        return value

    def names(self, values, what: str) -> list[str]:
        """The list ``values`` when it holds at most ``fans`` names of at most name_chars each."""
        self.count(values, self.fans, 'fans', what)
        for v in values:
            self.text(v, f'a name in {what}', name=True)
        return list(values)

    def count(self, values: Sized, bound: int, key: str, what: str) -> None:
        """Refuse a sequence longer than ``bound`` (the limit ``key``)."""
        if len(values) > bound:
            raise LimitError(f'{what} has {len(values)} entries, more than the {bound} allowed '
                             f'(limits.{key}); send fewer, or raise limits.{key} in the node\'s '
                             f'parameters')

    def plate_time(self, rows: int, per_row_s: float, what: str) -> float:
        """The plate time [s] of ``rows`` sweeps of ``per_row_s`` each; LimitError, stating it,
        when it or the row count is above the budget."""
        total = rows * per_row_s
        if rows > self.design_rows or total > self.plate_budget_s:
            raise LimitError(
                f'{what} has {rows} sweeps, about {duration_text(total)} of plate time '
                f'({per_row_s:g} s each), more than the budget of {self.design_rows} sweeps and '
                f'{duration_text(self.plate_budget_s)} (limits.design_rows, '
                f'limits.plate_budget_s): split it into smaller experiments')
        return total


DEFAULT_LIMITS = Limits()


def excerpt(value, chars: int = EXCERPT_CHARS, *, quote: bool = True) -> str:
    """A short excerpt of ``value`` for an error message: a string quoted (its repr; ``quote``
    False: as it is), anything else as its repr, cut to ``chars`` characters and then saying how
    long the whole was."""
    try:
        text = value if isinstance(value, str) else repr(value)
    except ValueError:   # an integer of more digits than Python prints (4300)
        text = f'<{type(value).__name__} too large to print>'
    cut = text if len(text) <= chars else text[:chars]
    shown = repr(cut) if quote and isinstance(value, str) else cut
    return shown if len(text) <= chars else f'{shown}... ({len(text)} characters in all)'


def duration_text(seconds: float) -> str:
    """'3 h 20 min', '45 s', '12 d 4 h' for messages."""
    s = float(seconds)
    if s < 120:
        return f'{s:.0f} s'
    if s < 7200:
        return f'{s / 60:.0f} min'
    if s < 172800:
        return f'{s // 3600:.0f} h {s % 3600 / 60:.0f} min'
    return f'{s // 86400:.0f} d {s % 86400 / 3600:.0f} h'


__all__ = ['DEFAULT_LIMITS', 'EXCERPT_CHARS', 'LimitError', 'Limits', 'duration_text', 'excerpt']
