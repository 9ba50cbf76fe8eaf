"""The bounds a coordinator request must meet before any of it is parsed (no ROS here).

Each ``check_*`` takes the request's fields as plain Python values and a ``core.limits.Limits``
and raises ``LimitError`` (what was too large, by how much, what to do; a short excerpt at most)
or returns quietly. They look at sizes only: what the fields mean (a target, a model, a design)
is checked afterwards by the code that parses them, within these sizes. A designed experiment
also states its plate time here, and one above the budget is refused with that figure.

``read_model`` then reads a set_model request's model (its text, or a file) and builds the prior
for the run; ``why`` words any refusal for the answer.
"""
from __future__ import annotations

from typing import Sequence

from ..core.errors import ConfigError, LimitError, WindShaperError
from ..core.limits import Limits, excerpt
from ..core.safe_yaml import read_text_file


def check_model_request(limits: Limits, model_yaml: str, path: str) -> None:
    """set_model: the YAML text (limits.yaml_bytes; the parser checks depth and anchors) and the
    path (limits.text_chars)."""
    if len(model_yaml) > limits.yaml_bytes:
        raise LimitError(f'the model_yaml text has {len(model_yaml)} characters, more than the '
                         f'{limits.yaml_bytes} bytes allowed (limits.yaml_bytes): no model file '
                         f'is that large; check what was sent')
    limits.text(path, 'the path')


def check_target_request(limits: Limits, target: str) -> None:
    """run_iteration: the target spec (limits.text_chars)."""
    limits.text(target, 'the target')


def check_collect_request(limits: Limits, name: str, design: str, fan_names: Sequence[str],
                          commands: Sequence[float], labels: Sequence[str],
                          per_row_s: float) -> float:
    """collect: every field's size, then the plate time of the table: its rows (len(commands) /
    len(fan_names)) times ``per_row_s`` [s] (a sweep and the settling before it). Returns the
    plate time [s]; LimitError, stating it, when above limits.plate_budget_s or
    limits.design_rows."""
    limits.text(name, 'the experiment name', name=True)
    limits.text(design, 'the design')
    limits.names(fan_names, 'fan_names')
    rows = -(-len(commands) // max(len(fan_names), 1))
    limits.plate_time(rows, per_row_s, 'the design')
    limits.count(commands, limits.design_rows * limits.fans, 'design_rows', 'commands')
    limits.count(labels, limits.design_rows, 'design_rows', 'labels')
    for label in labels:
        limits.text(label, 'a label', name=True)
    return rows * per_row_s


def check_hold_request(limits: Limits, fan_names: Sequence[str], pwm: Sequence[float]) -> None:
    """hold_point: as many names and commands as limits.fans at most."""
    limits.names(fan_names, 'fan_names')
    limits.count(pwm, limits.fans, 'fans', 'pwm')


def read_model(run, limits: Limits, text: str, path: str):
    """(text, source, model) of a set_model request for ``run`` (a ``ShapingRun``): the
    ``text`` when it has any (named by ``path`` when that is given too: the file the text came
    from), else the file at ``path`` (at most limits.yaml_bytes). Reads a file and builds a
    model: a node runs it off its executor. ConfigError says what is wrong."""
    source = f'{path} (sent as text)' if path else 'the model_yaml text'
    if not text.strip():
        if not path:
            raise ConfigError('give a model file as model_yaml text or as a path')
        source = path
        try:
            text = read_text_file(path, limits.yaml_bytes, limits)
        except OSError as exc:
            raise ConfigError(f'cannot read {path}: {exc.strerror or exc}') from None
    return text, source, run.model_from_text(text, source)


def why(exc: Exception) -> str:
    """A refusal's reason: a WindShaperError says it; anything else is named, shortly."""
    if isinstance(exc, WindShaperError):
        return str(exc)
    return f'unexpected {type(exc).__name__}: {excerpt(str(exc), quote=False)}'


__all__ = ['check_collect_request', 'check_hold_request', 'check_model_request',
           'check_target_request', 'read_model', 'why']
