"""The error bar of a reported finding: what the fit's own standard error leaves out.

A finding's parameter is fitted together with the model's free parameters on the training
cells. Its Gauss-Newton standard error treats every cell as an independent measurement of a
model of the right form; neither is true: samples of one sweep share turbulence and the sweep's
commands, and the model is not of the tunnel's form, so the candidate and the refitted model
parameters share out the misfit differently from one set of sweeps to the next. The reported
sigma therefore combines, in quadrature,

* the Gauss-Newton standard error of the fit on every training sweep (``candidate_std``), and
* a delete-one-sweep jackknife in which each refit moves *every* free parameter of the model
  (``fit_mask``), not the candidate's alone: how far the value moves when one sweep's commands
  are not there to pin it, with the thrust curves and widths free to take their share again.

* the model-form spread: how far the value moves when the model's own parameters are put back
  as given (the commissioned model, fitted on a tunnel without the effect) and the candidate's
  alone refitted around them. Refitted beside the candidate, the thrust curves and widths take
  a share of what the tunnel does that the model's form cannot put in the candidate's term (a
  wall layer's deficit partly read as narrower edge jets); held as commissioned they cannot.
  The two readings bracket what the data say about the parameter, and no statistic of one fit
  measures how they differ.

The jackknife is the sweep-level sandwich estimate (sweeps are the independent units); the
quadrature sum keeps the fit's own error where few sweeps make the jackknife noisy. Coverage
of the result (the truth within 2 sigma) is measured by bench/coverage.py: with the first two
parts alone a wall layer 6 cm thick read 5.1-5.3 cm +- 0.1 cm (none of 6 runs covered).
"""
from __future__ import annotations

import numpy as np

from ..model import param_slices, term_label
from .errors import FitError
from .fitting import FitResult, fit_model, jackknife_std
from .trial import by_parameter, fit_mask, node_of

__all__ = ['reported_std']


def reported_std(case, label: str, fit: FitResult, own_std: dict, *, max_nfev: int = 12) -> dict:
    """{parameter: sigma} of the term ``label`` in ``fit`` (on ``case.train``): the fit's own
    standard errors ``own_std``, the whole-model delete-one-sweep jackknife and the model-form
    spread (``form_spread``), in quadrature
    (``own_std`` as it is when the jackknife cannot be taken)."""
    sl = next((sl for node, sl in param_slices(fit.model) if term_label(node) == label), None)
    if sl is None or sl.stop == sl.start:
        return own_std
    mask = fit_mask(fit.model)
    free = np.flatnonzero(mask)
    try:
        jk_all = jackknife_std(fit.model, case.train, free, max_nfev=max_nfev)
    except FitError:
        return own_std
    # the candidate's entries of the free-parameter vector: every one of them is free
    jk = jk_all[np.searchsorted(free, np.arange(sl.start, sl.stop))]
    jk = by_parameter(node_of(fit.model, label), jk)
    form = by_parameter(node_of(fit.model, label), form_spread(case, fit, sl))
    out = {}
    for name, v in jk.items():
        own = np.asarray(own_std.get(name, [np.nan] * len(v)), float)
        parts = (own, np.asarray(v, float), np.asarray(form.get(name, np.zeros(len(v))), float))
        out[name] = np.sqrt(sum(np.nan_to_num(p) ** 2 for p in parts)).tolist()
    return out


def form_spread(case, fit: FitResult, sl: slice, *, max_nfev: int = 20) -> np.ndarray:
    """|theta as fitted - theta refitted alone with the model's own parameters as given| for
    the candidate's parameters ``sl`` of ``fit.model`` (zeros when the refit fails). The model's
    own parameters are matched by name: a wrapper keeps the names of what it wraps."""
    given = dict(zip(case.model.theta_names, np.asarray(case.model.theta, float)))
    theta = np.array(fit.model.theta, float)
    own = np.zeros(len(theta), bool)
    own[sl] = True
    for i, name in enumerate(fit.model.theta_names):
        if not own[i] and name in given:
            theta[i] = given[name]
    try:
        alone = fit_model(fit.model.with_theta(theta), case.train, free=own, max_nfev=max_nfev)
    except FitError:
        return np.zeros(sl.stop - sl.start)
    return np.abs(alone.theta - np.asarray(fit.model.theta, float)[sl])
