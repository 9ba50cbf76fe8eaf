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

* for a finding on a fan's footprint shape (an elongation), the loosened spread: how far the
  value moves when the commissioned parameters that describe the same footprint in other
  respects (where the jet lands, its width, its profile: the candidate's ``loosen`` kinds) are
  let free beside it. The model's round footprint is not the jet's form; where the sweeps see
  a footprint from one side only (an edge fan near the sweep disc's rim), the candidate takes
  up part of that misfit. On noise-free sweeps of a clean simulated tunnel the reference reads
  LM2's round jet as elongated 1.03-1.05 times at about 50 deg (a jet stretched 1.4 times at
  34 deg as 1.47); let free, its landing, width and profile take up a third to a half of that
  (1.05 -> 1.03, 1.47 -> 1.44). The rest is not seen by any reading here; with noise the
  loosened refit also carries the freed parameters' own scatter, so it is wider than that.

The jackknife is the sweep-level sandwich estimate (sweeps are the independent units); the
quadrature sum keeps the fit's own error where few sweeps make the jackknife noisy. Coverage
of the result (the truth within 2 sigma) is measured by bench/coverage.py: with the first two
parts alone a wall layer 6 cm thick read 5.1-5.3 cm +- 0.1 cm (none of 6 runs covered).
"""
from __future__ import annotations

import numpy as np

from ..model import param_slices, set_fixed, term_label, walk
from .errors import FitError
from .fitting import FitResult, fit_model, jackknife_std
from .trial import by_parameter, fit_mask, node_of

__all__ = ['reported_std', 'loosened_spread']


def reported_std(case, label: str, fit: FitResult, own_std: dict, *, max_nfev: int = 12,
                 loosen: tuple = ()) -> dict:
    """{parameter: sigma} of the term ``label`` in ``fit`` (on ``case.train``): the fit's own
    standard errors ``own_std``, the whole-model delete-one-sweep jackknife, the model-form
    spread (``form_spread``) and, with ``loosen`` (kinds of terms), the loosened spread
    (``loosened_spread``), in quadrature
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
    node = node_of(fit.model, label)
    form = by_parameter(node, form_spread(case, fit, sl))
    loose = by_parameter(node, loosened_spread(case, fit, label, loosen)) if loosen else {}
    out = {}
    for name, v in jk.items():
        own = np.asarray(own_std.get(name, [np.nan] * len(v)), float)
        parts = (own, np.asarray(v, float), np.asarray(form.get(name, np.zeros(len(v))), float),
                 np.asarray(loose.get(name, np.zeros(len(v))), float))
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


def loosened_spread(case, fit: FitResult, label: str, kinds: tuple, *,
                    max_nfev: int = 20) -> np.ndarray:
    """|theta as fitted - theta refitted with every parameter of the model's terms of ``kinds``
    let free as well| for the term ``label`` of ``fit.model`` (zeros when the refit fails or
    the model has no such term). Terms of these kinds elsewhere in the tree (other fans'
    shifts, say) are freed too: the refit moves what it must."""
    n = next((sl.stop - sl.start for node, sl in param_slices(fit.model)
              if term_label(node) == label), 0)
    if not any(getattr(t, 'kind', '') in kinds for t in walk(fit.model)):
        return np.zeros(n)
    loose = set_fixed(fit.model, False, lambda spec: spec.get('kind') in kinds)
    sl = next((sl for node, sl in param_slices(loose) if term_label(node) == label), None)
    if sl is None or sl.stop - sl.start != n:
        return np.zeros(n)
    try:
        refit = fit_model(loose, case.train, free=fit_mask(loose), max_nfev=max_nfev)
    except FitError:
        return np.zeros(n)
    as_fitted = np.asarray(loose.theta, float)[sl]
    return np.abs(np.asarray(refit.model.theta, float)[sl] - as_fitted)
