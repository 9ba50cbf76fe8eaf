"""Model files: a fitted prior saved as YAML, loadable for any fan array of the same groups."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import LimitError, ModelFileError
from ..core.safe_yaml import load_yaml, read_text_file, read_yaml_file
from ..core.geometry import FanArray
from .terms import Term, term_from_dict

FORMAT_VERSION = 1


def save_model(path, model: Term, **meta) -> Path:
    """Write ``model`` (and free-form metadata: where it was fitted, its RMSE) to ``path``.

    Written to a temporary file first and renamed, so a crash never leaves half a model."""
    return write_model_doc(path, {'wind_shaper_model': FORMAT_VERSION, **meta, 'model': model.to_dict()})


def write_model_doc(path, doc: dict) -> Path:
    """Write a model file's parsed ``doc`` to ``path`` through a temporary file and a rename."""
    path = Path(path)
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
    (``heldout_rmse_N``, `calibrate`), else the held-out model error with the measurement noise
    taken out (``heldout_model_rmse_N``, `model add`), else the fit's own (``rmse_N``); NaN when
    the file says none of them."""
    try:
        doc = read_yaml_file(path)
    except (OSError, yaml.YAMLError):
        return float('nan')
    if not isinstance(doc, dict):
        return float('nan')
    for key in ('heldout_rmse_N', 'heldout_model_rmse_N', 'rmse_N'):
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


#: The model file's section with the commissioning's field maps (``commissioning_maps_section``).
MAPS_KEY = 'commissioning_maps'


def key_points_digest(key_points) -> str:
    """A short fingerprint of key points (N, 2) [m], rounded to 0.1 mm: maps estimated at other
    key points are not this tunnel layout's."""
    pts = np.round(np.asarray(key_points, dtype=float).reshape(-1, 2) * 1e4).astype(np.int64)
    return hashlib.sha1(pts.tobytes()).hexdigest()[:16]


def commissioning_maps_section(maps, key_points) -> dict:
    """The ``commissioning_maps`` section of a model file: every map's commands [fraction] and its
    field estimate and std [N] at ``key_points`` (rounded to 0.1 mN), with the key points'
    fingerprint. ``maps``: (U, mean, std) triples."""
    return {'key_points': int(len(key_points)), 'key_points_digest': key_points_digest(key_points),
            'maps': [{'pwm': np.round(np.asarray(U, float), 6).tolist(),
                      'mean_N': np.round(np.asarray(mean, float), 4).tolist(),
                      'std_N': np.round(np.asarray(std, float), 4).tolist()} for U, mean, std in maps]}


def read_commissioning_maps(doc, key_points, n_fans: int) -> tuple[list, str]:
    """(maps, note) from a model file's parsed ``doc``: maps as (U (n_fans,), mean (N,), std (N,))
    triples, and why there are none when the file has a section that cannot be used here (other
    key points, other fans, malformed); ([], '') when the file has no such section."""
    section = doc.get(MAPS_KEY) if isinstance(doc, dict) else None
    if section is None:
        return [], ''
    why = ('the model file\'s commissioning maps are not used: {}; calibrate again with this '
           'config folder to have them')
    if not isinstance(section, dict) or not isinstance(section.get('maps'), list):
        return [], why.format('its commissioning_maps section is malformed')
    if section.get('key_points_digest') != key_points_digest(key_points):
        return [], why.format(f'they were estimated at other key points ({section.get("key_points")} '
                              f'against this tunnel\'s {len(key_points)})')
    out = []
    for i, m in enumerate(section['maps']):
        try:
            U, mean, std = (np.asarray(m[k], dtype=float) for k in ('pwm', 'mean_N', 'std_N'))
        except (KeyError, TypeError, ValueError):
            return [], why.format(f'map {i} lacks pwm, mean_N or std_N numbers')
        if (U.shape != (n_fans,) or mean.shape != (len(key_points),) or std.shape != mean.shape
                or not (np.all(np.isfinite(U)) and np.all(np.isfinite(mean)) and np.all(std >= 0))):
            return [], why.format(f'map {i} has {U.size} commands and {mean.size} values for '
                                  f'{n_fans} fans and {len(key_points)} key points, or numbers '
                                  f'that are not finite')
        out.append((U, mean, std))
    return out, ''


def commissioning_maps_in(source, key_points, n_fans: int, *, text: bool = False) -> tuple[list, str]:
    """``read_commissioning_maps`` of the model file at path ``source``, or of its text with
    ``text=True``; ([], note) when it cannot be read."""
    try:
        doc = load_yaml(source, 'model text') if text else read_yaml_file(source)
    except (OSError, yaml.YAMLError, LimitError) as exc:
        return [], f'the model file\'s commissioning maps are not used: it cannot be read ({exc})'
    return read_commissioning_maps(doc, key_points, n_fans)


def routing_text(drives) -> str:
    """What the wiring check found (``workbench.wiring``), from ((command meant for, fan it
    drives), ...): 'fans A and B look swapped' for an exchange, else 'the command for A drives
    B, ...'."""
    drives = [tuple(p) for p in drives]
    if len(drives) == 2 and drives[0] == drives[1][::-1]:
        return f'fans {drives[0][0]} and {drives[0][1]} look swapped'
    return 'the commands look misrouted: ' + ', '.join(f'the command for {a} drives {b}' for a, b in drives)


def wiring_warning(text: str) -> str:
    """What the commissioning's wiring check (``workbench.wiring``, kept by `calibrate` as
    ``wiring_check``) says against the model file's ``text``: a warning naming the fans whose
    command channels looked misrouted, else '' (no check kept, none found, or unreadable)."""
    try:
        doc = load_yaml(text, 'model text')
    except (yaml.YAMLError, LimitError):
        return ''
    check = doc.get('wiring_check') if isinstance(doc, dict) else None
    if not isinstance(check, dict):
        return ''
    drives, fans = check.get('drives'), check.get('swapped')
    if (isinstance(drives, list) and len(drives) >= 2
            and all(isinstance(p, list) and len(p) == 2 and all(isinstance(n, str) for n in p) for p in drives)):
        found = routing_text(drives)
    elif isinstance(fans, list) and len(fans) >= 2 and all(isinstance(n, str) for n in fans):
        # a file that keeps the fans but not the routing
        found = (f'fans {fans[0]} and {fans[1]} with their command channels swapped' if len(fans) == 2
                 else f'fans {", ".join(fans)} with their command channels misrouted')
    else:
        return ''
    return (f'the commissioning that fitted this model found {found}: it describes those fans in '
            f'the wrong places. Rewire their ESC leads (or correct their entries in `channels` in '
            f'config/fan_output.yaml), record the designed sweeps again and calibrate on those '
            f'before shaping with it')
