"""Model files: a fitted prior saved as YAML, loadable for any fan array of the same groups."""
from __future__ import annotations

from pathlib import Path

import yaml

from ..core.errors import LimitError, ModelFileError
from ..core.safe_yaml import load_yaml, read_text_file, read_yaml_file
from ..core.geometry import FanArray
from .terms import Term, term_from_dict

FORMAT_VERSION = 1


def save_model(path, model: Term, **meta) -> Path:
    """Write ``model`` (and free-form metadata: where it was fitted, its RMSE) to ``path``.

    Written to a temporary file first and renamed, so a crash never leaves half a model."""
    path = Path(path)
    doc = {'wind_shaper_model': FORMAT_VERSION, **meta, 'model': model.to_dict()}
    tmp = path.with_suffix(path.suffix + '.tmp')
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    tmp.replace(path)
    return path


def load_model(path, fans: FanArray) -> Term:
    """Read a model file written by ``save_model`` and build it for ``fans``."""
    path = Path(path)
    try:
        text = read_text_file(path)
    except FileNotFoundError:
        raise ModelFileError(f'model file {path} does not exist: fit one with `wind-shaper '
                             f'calibrate --data EXPERIMENT --out {path}` (sweeps from `wind-shaper '
                             f'collect`) or, on the simulated tunnel, `wind-shaper calibrate --sim '
                             f'--out {path}`') from None
    except OSError as exc:
        raise ModelFileError(f'model file {path} cannot be read ({exc})') from None
    except LimitError as exc:
        raise ModelFileError(f'model file {path} cannot be read: {exc}') from None
    return model_from_text(text, fans, source=str(path))


def model_error(path) -> float:
    """The prior's error per key point [N] as its calibration measured it: the held-out RMSE
    (``heldout_rmse_N``), else the fit's own (``rmse_N``); NaN when the file says neither."""
    try:
        doc = read_yaml_file(path)
    except (OSError, yaml.YAMLError):
        return float('nan')
    if not isinstance(doc, dict):
        return float('nan')
    for key in ('heldout_rmse_N', 'rmse_N'):
        value = doc.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0:
            return float(value)
    return float('nan')


def model_from_text(text: str, fans: FanArray, source: str = 'model text') -> Term:
    """Build a model from the text of a model file (e.g. one sent over a service).
    ``source`` names it in error messages."""
    try:
        doc = load_yaml(text, source)
    except yaml.YAMLError as exc:
        raise ModelFileError(f'{exc}; restore it or fit a new one with `wind-shaper '
                             f'calibrate`') from None
    if not isinstance(doc, dict) or doc.get('wind_shaper_model') != FORMAT_VERSION or 'model' not in doc:
        raise ModelFileError(f'{source} is not a wind_shaper model file (version {FORMAT_VERSION} '
                             f'with a "model" section); fit one with `wind-shaper calibrate`')
    try:
        return term_from_dict(doc['model'], fans)
    except ModelFileError as exc:
        raise ModelFileError(f'{source}: {exc}') from None
