"""How well a model matches sweeps: RMSE, R^2, largest error, per sweep, and held out.

Measured forces carry turbulence, so even a perfect model leaves an RMSE of about the noise's
standard deviation on raw samples. The *model error* on held-out sweeps separates the two:

    E[(y - m)^2] = model_error^2 + noise^2      (noise independent of the model)

The noise variance comes from the sweeps themselves: pairs of samples taken at (nearly) the same
place but at least ``min_dt`` apart in time have independent turbulence, so half the squared
difference of their forces (after removing the model's own difference, which takes out the field
gradient between the two positions) estimates it, as a function of the force. ``HeldOut``
computes that once per held-out set; ``model_rmse = sqrt(max(MSE - noise^2, 0))`` is then the error the model makes on the field
itself, comparable between models on the same sweeps.

Forces [N], positions [m], commands [fraction 0..1].
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..model import Term
from .data import FitData, SweepSet

__all__ = ['Scores', 'scores', 'evaluate', 'HeldOut', 'REVISIT_M', 'REVISIT_S']

#: A place a sweep's path visits twice: two samples within this distance [m] ...
REVISIT_M = 0.012
#: ... and at least this far apart in time [s], far enough for independent turbulence.
REVISIT_S = 0.5


@dataclass(frozen=True)
class Scores:
    """rmse [N], r2 [-] (1 - SSE / SST), max_error [N] (largest |residual|), bias [N] (mean of
    measured - model), n samples."""

    rmse: float
    r2: float
    max_error: float
    bias: float
    n: int

    def to_json(self) -> dict:
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def scores(pred: np.ndarray, y: np.ndarray) -> Scores:
    """Scores of predictions ``pred`` against measurements ``y`` (both (M,) [N])."""
    pred, y = np.asarray(pred, float), np.asarray(y, float)
    if len(y) == 0:
        return Scores(float('nan'), float('nan'), float('nan'), float('nan'), 0)
    r = y - pred
    sst = float(np.sum((y - y.mean()) ** 2))
    return Scores(float(np.sqrt(np.mean(r ** 2))), float(1 - r @ r / sst) if sst > 0 else float('nan'),
                  float(np.max(np.abs(r))), float(np.mean(r)), len(y))


def evaluate(model: Term, data: FitData, labels=None) -> dict:
    """Overall and per-sweep scores of ``model`` on ``data``: {'overall': Scores, 'per_sweep':
    {label: Scores}}."""
    pred = model(data.U, data.Z)
    out = {'overall': scores(pred, data.y), 'per_sweep': {}}
    for s in np.unique(data.sweep):
        m = data.sweep == s
        key = labels[s] if labels is not None and s >= 0 else str(int(s))
        out['per_sweep'][key] = scores(pred[m], data.y[m])
    return out


def _pairs(sweeps: SweepSet, max_distance: float, min_dt: float):
    """(pairs, blocks): index pairs (P, 2) into the pooled raw samples, same sweep, within
    ``max_distance`` [m], at least ``min_dt`` [s] apart; and each pooled sample's time block
    (M,), ``min_dt`` long and numbered across the sweeps (the turbulence of two blocks is
    independent, within one it is not)."""
    out, blocks, offset, first_block = [], [], 0, 0
    for s in sweeps.sweeps:
        clean = s.finite()
        if len(clean):
            block = np.floor((clean.times - clean.times.min()) / min_dt).astype(np.int64)
            blocks.append(block + first_block)
            first_block += int(block.max()) + 1
        if len(clean) > 1:
            p = cKDTree(clean.positions).query_pairs(max_distance, output_type='ndarray')
            if len(p):
                p = p[np.abs(clean.times[p[:, 0]] - clean.times[p[:, 1]]) >= min_dt]
                out.append(p + offset)
        offset += len(clean)
    return (np.vstack(out) if out else np.zeros((0, 2), dtype=int),
            np.concatenate(blocks) if blocks else np.zeros(0, dtype=np.int64))


def _clustered_variance_of_mean(e: np.ndarray, block_i: np.ndarray, block_j: np.ndarray) -> float:
    """The variance of mean(e) over pairs whose terms share noise through either sample's time
    block: two-way clustered (by the first sample's block, by the second's, less by both), and
    never below what independent pairs would give. A sample sits in many pairs and its
    neighbours in time share its gusts, so the pairs are far fewer independent terms than
    there are pairs."""
    P = len(e)

    def summed(ids):
        _, inverse = np.unique(ids, return_inverse=True)
        return float(np.sum(np.bincount(inverse.ravel(), weights=e) ** 2))

    both = block_i * (int(max(block_i.max(), block_j.max())) + 1) + block_j
    clustered = (summed(block_i) + summed(block_j) - summed(both)) / P ** 2
    return max(clustered, float(np.var(e)) / P)


class HeldOut:
    """Held-out sweeps, prepared once: their raw samples, and the noise estimate.

    ``evaluate(model)`` gives raw scores, the per-sweep RMSE and the model error
    (``model_rmse`` [N], see the module docstring). The noise is turbulence that grows with the
    force (the simulator's: 4 % of it plus 0.03 N), so its variance is fitted as
    b^2 + a^2 F^2 to the far-in-time pairs (within ``max_distance`` [m], at least ``min_dt`` [s]
    apart) and averaged over every held-out sample at the model's force: ``noise_sd`` [N].
    ``resolution`` [N] is the smallest model error the pairs can tell from zero (two standard
    errors of the noise variance, the pairs clustered by the samples' time blocks of
    ``min_dt``); a smaller estimate reads "at the noise floor".
    """

    def __init__(self, sweeps: SweepSet, *, max_distance: float = REVISIT_M, min_dt: float = REVISIT_S,
                 noise_sd: float | None = None):
        self.sweeps = sweeps
        self.data = sweeps.fit_data(cell=None)
        self.pairs, self._blocks = _pairs(sweeps, max_distance, min_dt)
        self.noise_sd = noise_sd
        self.resolution = float('nan')

    def estimate_noise(self, model: Term) -> float:
        """Noise sd [N] averaged over the held-out samples (NaN with fewer than 20 pairs); sets
        ``resolution``."""
        if len(self.pairs) < 20:
            return float('nan')
        from scipy.optimize import nnls
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        m = model(self.data.U, self.data.Z)
        d = (self.data.y[i] - self.data.y[j]) - (m[i] - m[j])
        half = d * d / 2
        F2 = (0.5 * (m[i] + m[j])) ** 2
        coef, _ = nnls(np.column_stack([np.ones(len(half)), F2]), half)
        var = coef[0] + coef[1] * m * m
        mean_var = float(np.mean(var))
        # standard error of the mean variance: pairs' spread around the fitted law, clustered by
        # the samples' time blocks (pairs sharing a sample or its gusts are not independent)
        pred = coef[0] + coef[1] * F2
        spread = _clustered_variance_of_mean(half - pred, self._blocks[i], self._blocks[j])
        se = float(np.sqrt(spread) * mean_var / max(float(np.mean(pred)), 1e-12))
        self.resolution = float(np.sqrt(2 * se))
        return float(np.sqrt(mean_var))

    def predict(self, model: Term) -> np.ndarray:
        return model(self.data.U, self.data.Z)

    def evaluate(self, model: Term, pred: np.ndarray | None = None) -> dict:
        if pred is None:
            pred = self.predict(model)
        if self.noise_sd is None:
            self.noise_sd = self.estimate_noise(model)
        raw = scores(pred, self.data.y)
        noise = self.noise_sd if np.isfinite(self.noise_sd) else 0.0
        model_rmse = float(np.sqrt(max(raw.rmse ** 2 - noise ** 2, 0.0)))
        per = {}
        for s in np.unique(self.data.sweep):
            m = self.data.sweep == s
            per[self.sweeps.labels[s]] = scores(pred[m], self.data.y[m])
        return {'raw': raw, 'model_rmse': model_rmse, 'noise_sd': float(self.noise_sd),
                'resolution': self.resolution, 'per_sweep': per}

    def mse(self, pred: np.ndarray) -> float:
        r = self.data.y - pred
        return float(np.mean(r * r))
