"""The reference model: the prior plus each fan's build, fitted once on the calibration batch.

Why: the paper's prior has one PWM-to-force polynomial per mount group and one footprint width.
Real fans differ from their group (the simulator draws thrust gains of 0.83-1.12, ~1 cm landing
offsets and +-6 % widths per fan; the rig's paper calls its field "strongly asymmetric"). Against
that prior, "fan LM2 delivers 17 % less thrust than the model assumes" is simply true of every
tunnel, so a diagnosis run against it would always report the build, and could not tell a fan
that has since worn from one that was always weak.

So the workbench diagnoses against a *reference* model: the prior wrapped in each fan's own
thrust gain, footprint width and landing offset (``FanGain``, ``FanWidth``, ``FanShift`` over
every fan), fitted on the calibration batch (each fan alone, plate held over and around its hub)
when the tunnel is commissioned. The build parameters are then *fixed* (the model file says so)
and only the group-level prior (polynomials and widths) is refitted to new sweeps. A finding is
then a change against the commissioned tunnel, or an effect the calibration batch cannot see
(swirl, jet interaction, a wall layer, a dead band, a background draft all need several fans,
the tunnel's edge, or low and high commands at once).

The gain per group and the width of the edge fans are normalised to a mean of 1 after the fit
(a gain common to a group is the group polynomial's business), so the reference is unique.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model import CalibrationPlan, collect_calibration
from ..model import (FanCurve, FanGain, FanShape, FanShift, FanWidth, Term, paper_prior, refix,
                     term_from_dict, walk)
from ..core.geometry import FanArray
from .data import FitData
from .fitting import FitResult, fit_model

__all__ = ['BUILD_KINDS', 'GROUP_KINDS', 'FREE_PARAMETERS', 'with_build', 'hold_geometry',
           'commission', 'commission_on', 'Reference', 'COMMISSIONING_PLAN']

#: Kinds of the per-fan build terms of a reference model.
BUILD_KINDS = ('fan_gain', 'fan_width', 'fan_shift')
#: Kinds of the per-group refinements (refitted with the prior on new data).
GROUP_KINDS = ('fan_curve', 'fan_shape')


def with_build(model: Term) -> Term:
    """``model`` wrapped in what the calibration batch can pin down beyond the prior, all at
    their null values: each fan's thrust gain (``FanGain``), each edge fan's footprint width
    (``FanWidth``) and each fan's landing offset (``FanShift``), and per mount group the bend of
    the thrust curve (``FanCurve``, cubic) and the flatness of the footprint (``FanShape``)."""
    fans = model.fans
    groups = [g for g in ('higher', 'lower', 'central') if fans.group_mask(g).any()]
    edge_groups = [g for g in groups if g != 'central']
    out = model
    if groups:
        out = FanCurve(fans, out, group=groups)
    if edge_groups:
        out = FanShape(fans, out, group=edge_groups, flatness=2.0)
    out = FanGain(fans, out)
    edge = [f.name for f in fans.fans if f.group != 'central']
    if edge:
        out = FanWidth(fans, out, fan=edge)
    return FanShift(fans, out)


def _normalise(model: Term, fans: FanArray) -> Term:
    """Move each group's mean gain into its polynomial and the edge fans' mean width scale
    into the jets' sigma (the model is unchanged; the split becomes unique)."""
    spec = model.to_dict()
    nodes = {}

    def visit(s):
        kind = s.get('kind')
        if kind in ('sum', 'product'):
            for t in s['terms']:
                visit(t)
            return
        nodes.setdefault(kind, s)
        if isinstance(s.get('term'), dict):
            visit(s['term'])

    visit(spec)
    gain, jets, ring, width = (nodes.get(k) for k in ('fan_gain', 'fan_jets', 'central_ring', 'fan_width'))
    if gain is not None and 'fan' not in gain and 'group' not in gain:
        g = np.asarray(gain['gain'], float)
        for group, owner, key in (('higher', jets, 'thrust_higher'), ('lower', jets, 'thrust_lower'),
                                  ('central', ring, 'thrust')):
            idx = fans.group_mask(group) & fans.enabled
            if owner is None or not idx.any():
                continue
            a = float(np.mean(g[idx]))
            g[idx] /= a
            owner[key] = (np.asarray(owner[key], float) * a).tolist()
        gain['gain'] = g.tolist()
    if width is not None and jets is not None:
        s = np.asarray(width['scale'], float)
        a = float(np.mean(s))
        width['scale'] = (s / a).tolist()
        jets['sigma'] = float(jets['sigma']) * a
    return term_from_dict(spec, fans)


#: Parameters a reference model keeps free: the PWM-to-force polynomials, which drift with the
#: supply voltage, air density and wear; everything geometric stays as commissioned.
FREE_PARAMETERS = {'fan_jets': ('thrust_higher', 'thrust_lower'), 'central_ring': ('thrust',)}


def hold_geometry(model: Term) -> Term:
    """A copy of ``model`` whose parameters are all fixed except ``FREE_PARAMETERS``."""
    return refix(model, lambda spec, cls: [h.name for h in cls.hypers
                                           if h.name not in FREE_PARAMETERS.get(spec['kind'], ())])


@dataclass(frozen=True)
class Reference:
    """A commissioned reference model: ``model`` (build fixed, group prior free), the fit on
    the calibration batch ``fit`` (all parameters free) and that batch as ``data``."""

    model: Term
    fit: FitResult
    data: FitData

    def build(self) -> dict:
        """Per fan: thrust gain, width scale, landing offset [m] as commissioned."""
        fans = self.model.fans
        nodes = {getattr(t, 'kind', ''): t for t in walk(self.model)}
        g, w, s = nodes.get('fan_gain'), nodes.get('fan_width'), nodes.get('fan_shift')
        out = {}
        for j, name in enumerate(fans.names):
            out[name] = {
                'gain': float(g.gain[g._where[j]]) if g is not None and j in g._where else 1.0,
                'width_scale': float(w.scale[w._where[j]]) if w is not None and j in w._where else 1.0,
                'offset_m': (s.shift_of(s._where[j]).tolist() if s is not None and j in s._where
                             else [0.0, 0.0])}
        return out


def commission(data: FitData, fans: FanArray, prior: Term | None = None) -> Reference:
    """Fit the reference model on a calibration batch ``data``: first the prior alone, then each
    fan's build around it, then everything together; normalise; fix the build."""
    prior = prior if prior is not None else paper_prior(fans)
    base = fit_model(prior, data, max_nfev=200).model
    wrapped = with_build(base)
    n_base = len(base.theta)
    step = fit_model(wrapped, data, free=np.arange(n_base, len(wrapped.theta)), max_nfev=100)
    joint = fit_model(step.model, data, max_nfev=200)
    model = _normalise(joint.model, fans)
    return Reference(hold_geometry(model), joint, data)


#: The calibration batch for commissioning: the paper's (each fan alone, 0..80 % PWM in 5 %
#: steps over its hub; footprint at one PWM) held three times longer and with the footprint
#: taken at six offsets out to 24 cm: the reference's build is what every later finding is
#: measured against, so it is worth a few more minutes of the tunnel once.
COMMISSIONING_PLAN = CalibrationPlan(samples_per_point=60, offsets=(0.04, 0.08, 0.12, 0.16, 0.20, 0.24))


def commission_on(tunnel, plan: CalibrationPlan = COMMISSIONING_PLAN, prior: Term | None = None) -> Reference:
    """Run the calibration batch on ``tunnel`` (``model.calibration.collect_calibration``) and
    commission the reference model on it."""
    data = FitData.from_measurements(collect_calibration(tunnel, plan))
    return commission(data, tunnel.geometry.fans, prior)
