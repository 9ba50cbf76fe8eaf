"""The library of candidate effects: physical hypotheses, each a way to extend a model.

Like a pysindy feature library, a ``Library`` is a list of *families* that generate concrete
candidates for a given model and tunnel: the thrust-gain family gives one candidate per fan
(``fan_gain[HM2]``), the swirl family one for the whole tunnel. A ``Candidate`` knows its
hypothesis in plain words, how to extend a model with its term (``make``) and where the term
belongs in the model (``placement``), the values its parameters start from when screened
(``starts``), their "no effect" values (``null``), and how to state a fitted result as a
finding ("fan HM2 delivers about 20 % less thrust than the model assumes (gain 0.80 +- 0.02)").

Placement: ``fan`` terms (per-fan wrappers, the central ring) go around the model's fan-resolved
core, inside swirl, dead band, wall layer, jet interaction and background; ``outer`` terms wrap
(or add to) the whole model. ``apply_candidate`` does that, so a candidate added after another
still sees the fans it is about.

Write your own family: any callable ``(model, geometry) -> list[Candidate]``; see
docs/workbench.md.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from ..model import (SWIRL_LAWS, Background, CentralRing, DeadBand, FanCurve, FanElongation, FanGain,
                     FanShape, FanShift, FanWidth, FanWrapper, JetInteraction, JetInteractionPower, Sum,
                     Swirl, SwirlFollows, SwirlQuadratic, Term, WallLayer, Wrapper, find_term,
                     has_fan_parts, walk)
from ..core.geometry import TunnelGeometry
from .errors import CandidateError

__all__ = ['Candidate', 'Library', 'default_library', 'apply_candidate', 'candidate_for_hidden_effect',
           'FAMILIES']


def _pm(value, std, fmt='{:.2f}'):
    """``value ± std``, with enough decimals to show the std's first digit."""
    if std is None or not np.isfinite(std):
        return fmt.format(value)
    base = int(fmt[3]) if fmt.startswith('{:.') and fmt[3].isdigit() else 2
    digits = base if std <= 0 else min(max(base, int(-np.floor(np.log10(std)))), 6)
    return f'{value:.{digits}f} ± {std:.{digits}f}'


@dataclass(frozen=True)
class Candidate:
    """One hypothesis. name: unique id (``fan_gain[HM2]``); family: its kind; title: short
    words (``thrust gain of fan HM2``); hypothesis: the physical story; make(model, **params):
    the model extended with the term (``params`` override the start values); placement: 'fan'
    or 'outer' (see the module docstring); label: ``term_label`` of the term in a model;
    starts: parameter sets to screen from; null: the "no effect" value of each parameter;
    describe(node, std): the finding in plain words, from the fitted term and the parameters'
    standard errors {name: array}."""

    name: str
    family: str
    title: str
    hypothesis: str
    make: Callable[..., Term]
    placement: str
    label: str
    null: dict
    describe: Callable[[Term, dict], str]
    starts: tuple = ({},)
    fans: tuple = field(default=())
    refine_always: bool = False
    # its effect shows with every fan off: judged on the held-out fans-off sweeps as well
    fans_off: bool = False
    # another form of its family, not screened by the selection: tried only when the family's
    # own candidates explain much of the residual but do not hold across sweeps
    # (``family_forms``)
    other_form: bool = False
    # kinds of the model's terms that describe the same footprint in other respects (where the
    # jet lands, its width, its profile); their commissioned parameters are let free in one of
    # the readings of the finding's error bar (``uncertainty.loosened_spread``)
    loosen: tuple = ()

    def params(self, node: Term) -> dict:
        """The fitted term's own parameters {name: float or list}."""
        return {k: (float(v) if np.ndim(v) == 0 else np.asarray(v, float).tolist())
                for k, v in node.get_params().items()}


# -- applying a candidate -------------------------------------------------------------------------

def _peel(model: Term):
    """(core, rebuild): the fan-resolved core under any outer field terms and whole-tunnel
    wrappers, and a function that puts a new core back in their place."""
    if isinstance(model, Sum) and not has_fan_parts(model.k2):
        core, rebuild = _peel(model.k1)
        k2 = model.k2
        return core, (lambda c: rebuild(c) + k2)
    if isinstance(model, Wrapper) and not isinstance(model, FanWrapper):
        core, rebuild = _peel(model.inner)
        return core, (lambda c: model.clone(term=rebuild(c)))
    return model, (lambda c: c)


def apply_candidate(model: Term, candidate: Candidate, **params) -> Term:
    """``model`` extended with ``candidate`` (its start values, overridden by ``params``),
    the term placed as the candidate's ``placement`` says."""
    if candidate.placement == 'fan':
        core, rebuild = _peel(model)
        return rebuild(candidate.make(core, **params))
    return candidate.make(model, **params)


# -- families -------------------------------------------------------------------------------------

def _enabled_fans(geometry: TunnelGeometry, edge_only=False):
    return [f.name for f in geometry.fans.fans
            if f.enabled and not (edge_only and f.group == 'central')]


def _gain_family(model, geometry):
    fans = geometry.fans
    out = []
    for name in _enabled_fans(geometry):
        def describe(node, std, name=name):
            g, s = float(node.gain[0]), float(std.get('gain', [np.nan])[0])
            more = 'more' if g > 1 else 'less'
            return (f'fan {name} delivers about {abs(g - 1) * 100:.0f} % {more} thrust than the model '
                    f'assumes (gain {_pm(g, s)})')
        out.append(Candidate(
            f'fan_gain[{name}]', 'fan_gain', f'thrust gain of fan {name}',
            f'fan {name} delivers a different thrust than the model assumes (worn or chipped '
            f'propeller, tired motor or ESC)',
            lambda m, name=name, **p: FanGain(fans, m, fan=name, **p), 'fan', f'fan_gain[{name}]',
            {'gain': 1.0}, describe, ({'gain': 1.0},), (name,)))
    return out


def _shift_family(model, geometry):
    fans = geometry.fans
    out = []
    for name in _enabled_fans(geometry):
        def describe(node, std, name=name):
            d = np.asarray(node.shift, float)
            s = np.asarray(std.get('shift', [np.nan, np.nan]), float)
            ang = np.degrees(np.arctan2(d[1], d[0]))
            return (f'the jet of fan {name} lands {np.hypot(*d) * 100:.1f} cm from where the model puts '
                    f'it, towards {ang:.0f} deg from +x (dx {_pm(d[0] * 100, s[0] * 100, "{:.1f}")} cm, '
                    f'dy {_pm(d[1] * 100, s[1] * 100, "{:.1f}")} cm): a tilted or mis-mounted fan')
        out.append(Candidate(
            f'fan_shift[{name}]', 'fan_shift', f'landing offset of fan {name}',
            f'the jet of fan {name} lands off its hub (a tilted or mis-mounted fan)',
            lambda m, name=name, **p: FanShift(fans, m, fan=name, **p), 'fan', f'fan_shift[{name}]',
            {'shift': [0.0, 0.0]}, describe, ({'shift': [0.0, 0.0]},), (name,)))
    return out


def _width_family(model, geometry):
    fans = geometry.fans
    out = []
    picks = [(n, {'fan': n}, f'fan {n}') for n in _enabled_fans(geometry, edge_only=True)]
    picks += [(g, {'group': g}, f'the {g}-mounted fans') for g in ('higher', 'lower')
              if (fans.group_mask(g) & fans.enabled).any()]
    for key, sel, who in picks:
        def describe(node, std, who=who):
            s, e = float(node.scale[0]), float(std.get('scale', [np.nan])[0])
            word = 'wider' if s > 1 else 'narrower'
            return (f'the footprint of {who} is about {abs(s - 1) * 100:.0f} % {word} than the model '
                    f'assumes (width scale {_pm(s, e)})')
        out.append(Candidate(
            f'fan_width[{key}]', 'fan_width', f'footprint width of {who}',
            f'the jet of {who} spreads wider or narrower than the model assumes',
            lambda m, sel=sel, **p: FanWidth(fans, m, **sel, **p), 'fan', f'fan_width[{key}]',
            {'scale': 1.0}, describe, ({'scale': 1.05},),
            (key,) if 'fan' in sel else tuple(f.name for f in fans.fans if f.group == key)))
    return out


def _elongation_family(model, geometry):
    fans = geometry.fans
    side = geometry.plate_side
    out = []
    for name in _enabled_fans(geometry, edge_only=True):
        def describe(node, std, name=name):
            r, a = float(node.ratio[0]), float(node.angle[0])
            a = (a + np.pi / 2) % np.pi - np.pi / 2
            sr = float(std.get('ratio', [np.nan])[0])
            sa = float(std.get('angle', [np.nan])[0])
            return (f'the jet of fan {name} is elongated: stretched {_pm(r, sr)} times as long as wide '
                    f'along {_pm(np.degrees(a), np.degrees(sa), "{:.0f}")} deg from +x (a bent guide vane '
                    f'or tilted mount)')
        out.append(Candidate(
            f'fan_elongation[{name}]', 'fan_elongation', f'elongated footprint of fan {name}',
            f'the jet of fan {name} is stretched along one direction (bent guide vane, tilted mount)',
            lambda m, name=name, **p: FanElongation(fans, m, fan=name, plate_side=side, **p), 'fan',
            f'fan_elongation[{name}]', {'ratio': 1.0}, describe,
            tuple({'ratio': 1.2, 'angle': a} for a in (np.pi / 4, -np.pi / 4)), (name,),
            loosen=('fan_shift', 'fan_width', 'fan_shape')))
    return out


def _group_refinements(model, geometry):
    """Thrust-curve bend and footprint flatness per mount group (part of a commissioned
    reference; offered when the model has none)."""
    fans = geometry.fans
    kinds = {getattr(t, 'kind', '') for t in walk(model)}
    out = []
    groups = [g for g in ('higher', 'lower', 'central') if (fans.group_mask(g) & fans.enabled).any()]
    if 'fan_curve' not in kinds:
        for g in groups:
            def describe(node, std, g=g):
                b, s = float(node.bend[0]), float(std.get('bend', [np.nan])[0])
                return (f'the thrust of the {g}-mounted fans grows {"faster" if b > 0 else "slower"} than '
                        f'the quadratic curve at high commands (curve bend {_pm(b, s)}, i.e. thrust '
                        f'x (1 {b:+.2f} U))')
            out.append(Candidate(
                f'fan_curve[{g}]', 'fan_curve', f'thrust-curve bend of the {g} fans',
                f'the PWM-to-thrust curve of the {g} fans is not quadratic',
                lambda m, g=g, **p: FanCurve(fans, m, group=g, **p), 'fan', f'fan_curve[{g}]',
                {'bend': 0.0}, describe, ({'bend': 0.2},)))
    if 'fan_shape' not in kinds:
        for g in groups:
            if g == 'central':
                continue
            def describe(node, std, g=g):
                b, s = float(node.flatness[0]), float(std.get('flatness', [np.nan])[0])
                return (f'the footprints of the {g}-mounted fans are {"flat-topped" if b > 2 else "peaked"} '
                        f'rather than Gaussian (exp(-(d/sigma)^p), p = {_pm(b, s)})')
            out.append(Candidate(
                f'fan_shape[{g}]', 'fan_shape', f'footprint flatness of the {g} fans',
                f'the jets of the {g} fans are flat-topped, not Gaussian',
                lambda m, g=g, **p: FanShape(fans, m, group=g, **p), 'fan', f'fan_shape[{g}]',
                {'flatness': 2.0}, describe, ({'flatness': 2.3},)))
    return out


def _swirl_family(model, geometry):
    fans = geometry.fans
    if (any(getattr(t, 'kind', '') in ('swirl', 'swirl_quadratic', 'swirl_follows') for t in walk(model))
            or len(set(fans.spin_sign)) < 2):
        return []

    def describe(node, std):
        g, s = float(node.gain), float(std.get('gain', [np.nan])[0])
        c, cs = float(node.curvature), float(std.get('curvature', [np.nan])[0])
        at20 = g * 0.2 + c * 0.04
        sense = 'counter-clockwise' if at20 > 0 else 'clockwise'
        quad = (f', plus {_pm(c, cs)} rad x b|b| (the angle grows faster than the imbalance b)'
                if node.kind == 'swirl_quadratic' else '')
        return (f'the field turns {sense} about the tunnel axis when the CCW fans out-thrust the CW ones '
                f'(propeller swirl the straightener leaves): {_pm(g, s)} rad per unit of '
                f'b = (T_ccw - T_cw) / T{quad}, e.g. {abs(np.degrees(at20)):.0f} deg at a 20 % imbalance')
    story = 'residual propeller swirl turns the field about the axis when CW and CCW thrusts are unbalanced'
    return [Candidate('swirl', 'swirl', 'swirl rotation of the field', story,
                      lambda m, **p: Swirl(fans, m, **p), 'outer', 'swirl',
                      {'gain': 0.0}, describe, ({'gain': 0.3}, {'gain': -0.3})),
            # the wider form: an angle that grows faster (or slower) than the imbalance
            Candidate('swirl_quadratic', 'swirl', 'swirl rotation of the field, growing faster than '
                      'the imbalance', story + ', by an angle not proportional to the imbalance',
                      lambda m, **p: SwirlQuadratic(fans, m, **p), 'outer', 'swirl_quadratic',
                      {'gain': 0.0, 'curvature': 0.0}, describe,
                      ({'gain': 0.3, 'curvature': 0.0}, {'gain': -0.3, 'curvature': 0.0}))
            ] + [_swirl_form(fans, law) for law in SWIRL_LAWS]


def _swirl_form(fans, law: str) -> Candidate:
    """The swirl family's other form ``law`` (``model.SwirlFollows``), tried by
    ``family_forms`` only."""
    def describe(node, std):
        g, s = float(node.gain), float(std.get('gain', [np.nan])[0])
        sense = 'counter-clockwise' if g > 0 else 'clockwise'
        ref = f' (thrust_ref {node.thrust_ref:g} N)' if law != 'sign' else ''
        return (f'the field turns {sense} about the tunnel axis by an angle linear {SWIRL_LAWS[law]}'
                f'{ref}, not in the CW/CCW imbalance ratio the swirl candidate has: {_pm(g, s)} rad '
                f'per unit of it (propeller swirl the straightener leaves)')
    return Candidate(f'swirl_{law}', 'swirl', f'swirl rotation of the field, its angle linear '
                     f'{SWIRL_LAWS[law]}', 'residual propeller swirl turns the field about the axis, '
                     f'by an angle linear {SWIRL_LAWS[law]}',
                     lambda m, **p: SwirlFollows(fans, m, follows=law, **p), 'outer', 'swirl_follows',
                     {'gain': 0.0}, describe, ({'gain': 0.3}, {'gain': -0.3}), other_form=True)


def _interaction_family(model, geometry):
    fans = geometry.fans
    if (any(getattr(t, 'kind', '') in ('jet_interaction', 'jet_interaction_power') for t in walk(model))
            or fans.n_fans < 2):
        return []
    side = geometry.plate_side

    def describe(node, std):
        k, s = float(node.strength), float(std.get('strength', [np.nan])[0])
        if node.kind != 'jet_interaction_power':
            return (f'neighbouring jets entrain each other and fill the gap between them: an extra '
                    f'{_pm(k, s)} x sqrt(T_i T_j) between each pair of neighbours ({len(node.pairs)} pairs, '
                    f'width x{float(node.width):.2f} of the jets\')')
        p, ps = float(node.exponent), float(std.get('exponent', [np.nan])[0])
        ref = node.thrust_ref
        grows = 'faster than' if p > 0.55 else 'slower than' if p < 0.45 else 'about as fast as'
        return (f'neighbouring jets merge and fill the gap between them with a force that grows '
                f'{grows} the geometric mean of the two thrusts: an extra {_pm(k, s)} x {ref:g} N x '
                f'(T_i T_j / ({ref:g} N)^2)^p with thrust exponent p = {_pm(p, ps)} (1/2 would be '
                f'sqrt(T_i T_j)) between each pair of neighbours ({len(node.pairs)} pairs), spread '
                f'over {float(node.width):.2f} x the jets\' width')
    story = 'neighbouring jets entrain each other and fill the gap between them'
    return [Candidate('jet_interaction', 'jet_interaction', 'interaction of neighbouring jets', story,
                      lambda m, **p: JetInteraction(fans, m, plate_side=side, **p), 'outer',
                      'jet_interaction', {'strength': 0.0}, describe, ({'strength': 0.1, 'width': 1.0},),
                      refine_always=True),
            # the wider form: a gap force growing with another power of the two thrusts
            Candidate('jet_interaction_power', 'jet_interaction',
                      'interaction of neighbouring jets, with a free thrust exponent',
                      story + ', by a force that grows with a free power of the two thrusts',
                      lambda m, **p: JetInteractionPower(fans, m, plate_side=side, **p), 'outer',
                      'jet_interaction_power', {'strength': 0.0}, describe,
                      ({'strength': 0.1, 'width': 1.0, 'exponent': 0.5},
                       {'strength': 0.1, 'width': 1.0, 'exponent': 1.0}),
                      refine_always=True)]


def _wall_family(model, geometry):
    fans = geometry.fans
    if any(getattr(t, 'kind', '') == 'wall_layer' for t in walk(model)):
        return []
    shape = geometry.extra.get('wall_shape', 'round') if geometry.extra else 'round'

    def describe(node, std):
        d, s = float(node.thickness), float(std.get('thickness', [np.nan])[0])
        return (f'the flow slows near the tunnel wall: a boundary layer about {d * 100:.1f} cm thick '
                f'(thickness {_pm(d * 100, s * 100, "{:.1f}")} cm at the {node.wall_radius:.2f} m wall)')
    return [Candidate('wall_layer', 'wall_layer', 'wall boundary layer',
                      'the flow slows in a boundary layer at the tunnel wall',
                      lambda m, **p: WallLayer(fans, m, wall_radius=geometry.wall_radius, shape=shape,
                                               plate_side=geometry.plate_side, **p),
                      'outer', 'wall_layer', {}, describe,
                      ({'thickness': 0.01}, {'thickness': 0.05}))]


def _ring_family(model, geometry):
    fans = geometry.fans
    central = fans.group_mask('central') & fans.enabled
    if not central.any() or any(isinstance(t, CentralRing) for t in walk(model)):
        return []

    def describe(node, std):
        return (f'the central fan raises the flow on a ring around it rather than over its hub '
                f'(ring offset {float(node.offset):.2f}, width {float(node.sigma):.2f} m, thrust '
                f'{np.round(node.thrust, 2).tolist()})')

    def make(m, **p):
        return m + CentralRing(fans, **p)
    return [Candidate('central_ring', 'central_ring', "the central fan's ring",
                      'the low-mounted central fan lifts the flow on a ring over the edge fans',
                      make, 'fan', 'central_ring', {}, describe, ({},))]


def _background_family(model, geometry):
    fans = geometry.fans
    if any(getattr(t, 'kind', '') == 'background' for t in walk(model)):
        return []

    def describe(node, std):
        f, s = float(node.force), float(std.get('force', [np.nan])[0])
        return (f'a uniform background {"updraft" if f > 0 else "downdraft"} of {_pm(abs(f), s)} N acts '
                f'on the plate whatever the fans do (room ventilation, stack effect; or the force sensor\'s zero '
                f'is off: the data cannot tell the two apart)')

    def make(m, **p):
        return m + Background(fans, **p)
    return [Candidate('background', 'background', 'background offset',
                      'a uniform updraft adds the same force everywhere, even with all fans off',
                      make, 'outer', 'background', {'force': 0.0}, describe, ({'force': 0.1},),
                      refine_always=True, fans_off=True)]


def _dead_band_family(model, geometry):
    fans = geometry.fans
    if any(getattr(t, 'kind', '') == 'dead_band' for t in walk(model)):
        return []

    def describe(node, std):
        t, s = float(node.threshold), float(node.saturation)
        st = float(std.get('threshold', [np.nan])[0])
        ss = float(std.get('saturation', [np.nan])[0])
        return (f'the fans do nothing below {t * 100:.0f} % PWM and gain nothing above {s * 100:.0f} % '
                f'(ESC dead band {_pm(t, st, "{:.3f}")}, saturation {_pm(s, ss, "{:.3f}")})')
    return [Candidate('dead_band', 'dead_band', 'PWM dead band and saturation',
                      'the ESCs ignore small commands and saturate at high ones',
                      lambda m, **p: DeadBand(fans, m, **p), 'outer', 'dead_band',
                      {'threshold': 0.0, 'saturation': 1.0}, describe,
                      ({'threshold': 0.05, 'saturation': 0.95}, {'threshold': 0.1, 'saturation': 0.8}),
                      refine_always=True)]


#: Every family of the default library, by name.
FAMILIES = {
    'fan_gain': _gain_family, 'fan_shift': _shift_family, 'fan_width': _width_family,
    'fan_elongation': _elongation_family, 'group_refinements': _group_refinements,
    'swirl': _swirl_family, 'jet_interaction': _interaction_family, 'wall_layer': _wall_family,
    'central_ring': _ring_family, 'background': _background_family, 'dead_band': _dead_band_family,
}


class Library:
    """A list of candidate families. ``candidates(model, geometry)`` expands them; ``extra``
    candidates (e.g. built around a user-written term) are appended as they are."""

    def __init__(self, families: Sequence | None = None, extra: Sequence[Candidate] = ()):
        if families is None:
            families = list(FAMILIES)
        self.families = [FAMILIES[f] if isinstance(f, str) else f for f in families]
        for f in families:
            if isinstance(f, str) and f not in FAMILIES:
                raise CandidateError(f'unknown candidate family {f!r}; known: {sorted(FAMILIES)}')
        self.extra = list(extra)

    def candidates(self, model: Term, geometry: TunnelGeometry) -> list[Candidate]:
        out = []
        for family in self.families:
            out += family(model, geometry)
        out += self.extra
        names = [c.name for c in out]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise CandidateError(f'candidate names must be unique; repeated: {dup}')
        return out

    def get(self, model: Term, geometry: TunnelGeometry, name: str) -> Candidate:
        for c in self.candidates(model, geometry):
            if c.name == name:
                return c
        raise CandidateError(f'no candidate {name!r} for this model; candidates: '
                             f'{[c.name for c in self.candidates(model, geometry)]}')


def default_library() -> Library:
    return Library()


def candidate_for_hidden_effect(effect) -> tuple[str, dict]:
    """(candidate name, {parameter: true value}) that explains a simulator hidden effect
    (``wind_shaper.sim.effects``), for checking a diagnosis against ``effect.truth()``."""
    t = effect.truth()
    name = effect.name
    if name == 'weak_fan':
        return f'fan_gain[{t["fan"]}]', {'gain': t['gain']}
    if name == 'tilted_fan':
        return f'fan_shift[{t["fan"]}]', {'shift': list(t['shift'])}
    if name == 'elongated_footprint':
        return f'fan_elongation[{t["fan"]}]', {'ratio': t['ratio'], 'angle': t['angle']}
    if name == 'swirl':
        return 'swirl', {'gain': t['gain']}
    if name == 'wall_boundary_layer':
        return 'wall_layer', {'thickness': t['thickness']}
    if name == 'jet_interaction':
        return 'jet_interaction', {'strength': t['strength']}
    if name == 'dead_band':
        return 'dead_band', {'threshold': t['threshold'], 'saturation': t['saturation']}
    if name == 'background_draft':
        return 'background', {'force': t['force']}
    if name == 'quadratic_swirl':  # swirl in another form: the family's wider candidate
        return 'swirl_quadratic', {'gain': t['gain'], 'curvature': t['curvature']}
    if name == 'merging_jets':  # jet interaction in another form: the family's wider candidate
        # the same law at the same reference thrust; the bridge's shape (elongated, its own width)
        # has no counterpart, so only strength and exponent compare
        return 'jet_interaction_power', {'strength': t['strength'], 'exponent': t['exponent']}
    raise CandidateError(f'no library candidate stands for the hidden effect {name!r}')


def node_of(model: Term, candidate: Candidate):
    """The candidate's term inside a model (None if absent)."""
    return find_term(model, candidate.label)


__all__.append('node_of')
