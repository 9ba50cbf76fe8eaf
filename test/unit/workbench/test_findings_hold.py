"""Ways a library term can fit physics the library lacks, or be perturbed by it, and the checks
that decide (wind_shaper.workbench.diagnose): cases from the detection bench (bench/detection.py,
12 sweeps) where a wrong effect was named or a real one missed before."""
import pytest

from wind_shaper.sim import make_effect
from wind_shaper.workbench.commands import simulated_sweeps
from wind_shaper.workbench.consistency import (check_across_load, check_across_space,
                                               check_beside_discrepancy)
from wind_shaper.workbench.diagnose import Diagnosis
from wind_shaper.workbench.library import candidate_for_hidden_effect

pytestmark = pytest.mark.slow


def _diagnose(wb_setup, reference, effects, seed):
    built = [make_effect(e) for e in effects]
    data = simulated_sweeps(wb_setup.make_sim(seed=seed, effects=built), 12, seed=seed)
    return Diagnosis().fit(reference, data, wb_setup.geometry)


def _the_finding(d, known, name):
    """The one finding of ``d``: nothing wrong named, and it is the candidate ``name``."""
    _assert_nothing_wrong(d, known)
    (t,) = d.steps_
    assert t.candidate.name == name, d.summary()
    return t


def _assert_nothing_wrong(d, known):
    expected, _ = candidate_for_hidden_effect(make_effect(known))
    assert {t.candidate.name for t in d.steps_} <= {expected}, d.summary()
    for t in d.steps_:
        assert t.check is not None and t.check.passed, (t.candidate.name, t.reasons)


def test_a_fan_that_only_looks_strong_against_the_refitted_curves_is_not_named(wb_setup, reference):
    # a stand's wake over HM1 and a weak HM2 pull the HM group's refitted thrust curve down:
    # unchanged HM3 then came out "17 % stronger", consistently in every sweep
    d = _diagnose(wb_setup, reference, ('stand_wake', 'weak_fan'), 103)
    _assert_nothing_wrong(d, 'weak_fan')
    (hm3,) = [t for t in d.demoted_ if t.candidate.name == 'fan_gain[HM3]']
    assert hm3.check.passed is False
    assert 'leans on the refitted thrust curves' in hm3.check.reasons[-1]
    assert 'leans on the refitted thrust curves' in d.summary()


def test_a_real_weak_fan_holds_against_the_curves_as_commissioned(diagnosed):
    d, _ = diagnosed('weak_fan')
    assert [t.candidate.name for t in d.steps_] == ['fan_gain[HM2]']
    assert d._leans_on_curves(d.steps_) is None


def test_a_jet_shape_that_patches_one_side_of_its_footprint_is_not_named(wb_setup, reference):
    # a blocked honeycomb patch beside HM2's hub passes 35 % less of the flow, the same in every
    # sweep: as HM2's elongation and width it passed the check across sweeps
    d = _diagnose(wb_setup, reference, ('honeycomb_blockage', 'tilted_fan'), 102)
    _assert_nothing_wrong(d, 'tilted_fan')
    shapes = [t for t in d.demoted_ if t.candidate.family in ('fan_elongation', 'fan_width')]
    assert shapes, d.summary()
    assert any('does not hold on both sides of its footprint' in r
               for t in shapes for r in t.check.reasons)


def test_a_real_elongated_jet_holds_on_both_sides_of_its_footprint(diagnosed):
    d, _ = diagnosed('elongated_footprint')
    (t,) = d.steps_
    assert t.candidate.name == 'fan_elongation[LM2]'
    without = d._rebuild([])
    assert check_across_space(d.final_.model, t.candidate.label, t.candidate.null, d.train_,
                              without.model) == ''


def test_a_tilted_fan_beside_a_blocked_patch_holds_beside_a_discrepancy(wb_setup, reference):
    # the blocked patch perturbs LM2's landing offset differently in every sweep (4 of 7 sweeps
    # disagree alone); refitted jointly with a discrepancy model the sweeps agree again
    d = _diagnose(wb_setup, reference, ('honeycomb_blockage', 'tilted_fan'), 100)
    t = _the_finding(d, 'tilted_fan', 'fan_shift[LM2]')
    beside = t.check.beside
    assert beside is not None and beside.passed, beside
    # the joint estimate is nearer the truth (4 cm along x) than the pooled fit the patch biases
    _, truth = candidate_for_hidden_effect(make_effect('tilted_fan'))
    assert abs(beside.mean[0] - truth['shift'][0]) < abs(t.params['shift'][0] - truth['shift'][0])
    assert 'only with a discrepancy model beside it' in d.summary()


def test_beside_a_discrepancy_a_weak_fan_holds_and_a_patch_does_not(wb_setup, reference):
    # the stand's wake over HM1 perturbs HM2's gain in one sweep (alone: chance of the spread
    # 4e-4) and reads as offsets of LM2's and HM1's jets; beside a discrepancy model HM2's gain
    # holds; LM2's offset shrinks beside a discrepancy with the model's scale (beside bumps
    # alone it predicts the held-out sweeps no better than a discrepancy without it), and HM1's
    # only hides its spread
    d = _diagnose(wb_setup, reference, ('stand_wake', 'weak_fan'), 105)
    t = _the_finding(d, 'weak_fan', 'fan_gain[HM2]')
    assert t.check.beside.passed
    refused = {t.candidate.name: t for t in d.demoted_}
    assert 'the discrepancy takes up what it explained' in refused['fan_shift[LM2]'].check.reasons[-1]
    # HM1's offset: its values beside a discrepancy are as spread as without one, behind error
    # bars so wide that the old spread would pass too (before rule 1b: it shrank to a quarter)
    assert 'hides the spread behind wider error bars' in refused['fan_shift[HM1]'].check.reasons[-1]
    for name in ('fan_shift[LM2]', 'fan_shift[HM1]'):
        assert not refused[name].check.beside.passed


def test_a_wake_across_one_jet_is_not_named_as_that_fan_s_gain(wb_setup, reference):
    # the stand's wake alone (seed 207, found on seeds no setting was tuned on): a strip across
    # HM1's jet reads as HM1 delivering 12 % less thrust in every sweep once a discrepancy takes
    # up the rest; on the two sides of HM1's footprint the "gain" differs
    d = _diagnose(wb_setup, reference, ('stand_wake',), 207)
    assert d.steps_ == [], d.summary()
    (hm1,) = [t for t in d.demoted_ if t.candidate.name == 'fan_gain[HM1]']
    assert hm1.check.beside is not None and hm1.check.beside.passed
    assert 'does not hold on both sides of its footprint' in hm1.check.reasons[-1]
    assert 'library lacks' in d.summary()


def test_a_wall_layer_beside_a_starved_inlet_holds_beside_the_models_own_scale(wb_setup, reference):
    # a starved inlet scales every fan's thrust with the mean command, so the wall layer's
    # thickness spreads from sweep to sweep (3.1-6.2 cm) even beside bumps x command features,
    # which cannot follow the model's own field as the commands vary; with Kennedy and O'Hagan's
    # scale of the model (a share that follows the total thrust) beside it the sweeps agree
    d = _diagnose(wb_setup, reference, ('plenum_starvation', 'wall_boundary_layer'), 101)
    t = _the_finding(d, 'wall_boundary_layer', 'wall_layer')
    assert t.check.beside.passed
    _, truth = candidate_for_hidden_effect(make_effect('wall_boundary_layer'))
    assert abs(t.check.beside.mean[0] - truth['thickness']) < 0.015, t.check.beside.mean
    assert 'only with a discrepancy model beside it' in d.summary()
    # bumps alone do not settle it: the same check without the model's scale fails
    final = d.final_.model
    without = d.baseline_.model
    plain = check_beside_discrepancy(final, t.candidate.label, t.candidate.null, d.train_, d.heldout_,
                                     without, wb_setup.geometry, t.check.informative)
    assert not plain.passed, plain


def test_a_background_draft_beside_a_side_draft_is_judged_where_the_fans_are_off(wb_setup, reference):
    # the draft bends the plume and dominates the fans-on residual: the background (0.3 N)
    # lowers the held-out error only 9 % overall, but it is all of the fans-off sweeps' error
    d = _diagnose(wb_setup, reference, ('side_draft', 'background_draft'), 100)
    t = _the_finding(d, 'background_draft', 'background')
    assert t.gain < 0.2 <= t.gain_off
    assert abs(t.params['force'] - 0.3) < 0.05, t.params
    assert 'It shows with every fan off' in d.summary()
    # the draft alone leaves nothing on the fans-off sweeps: no background is named
    alone = _diagnose(wb_setup, reference, ('side_draft',), 100)
    assert 'background' not in {t.candidate.name for t in alone.steps_}, alone.summary()


def test_a_discrepancy_that_only_widens_the_error_bars_rescues_nothing(wb_setup, reference):
    # held-out physics (seed 300): LM1's ESC picks up a quarter of HM1's PWM, so LM1 looks
    # 15-100 % stronger depending on the two commands. Beside a discrepancy whose bump over LM1
    # times LM1's command shares the gain's own columns, each sweep's gain is ten times looser
    # and the spread looked ordinary: "LM1 delivers about 35 % more thrust" was named. The
    # values spread as much as without the discrepancy, so it is refused.
    d = _diagnose(wb_setup, reference, ('esc_crosstalk',), 300)
    assert d.steps_ == [], d.summary()
    (lm1,) = [t for t in d.demoted_ if t.candidate.name == 'fan_gain[LM1]']
    assert not lm1.check.beside.passed
    assert 'spread as much as without one' in lm1.check.beside.reasons[0]
    assert 'library lacks' in d.summary()
    # without the rule the same check passes: the rule is what refuses it
    final, without = d._rebuild([lm1]).model, d.baseline_.model
    loose = check_beside_discrepancy(final, lm1.candidate.label, lm1.candidate.null, d.train_,
                                     d.heldout_, without, wb_setup.geometry, lm1.check.informative,
                                     scale_features=())
    assert loose.passed, loose.reasons


def test_a_return_flow_down_the_wall_is_not_named_a_boundary_layer(wb_setup, reference):
    # held-out physics (seed 400): air comes back down along the wall, a deficit that follows
    # the whole tunnel's mean thrust. In every sweep it reads as a 1-2 cm boundary layer (each
    # sweep averages strong and weak jets), but beside a weak jet the "layer" is twice as thick
    # as beside a strong one: a share of the local flow it is not
    d = _diagnose(wb_setup, reference, ('wall_return_flow',), 400)
    assert d.steps_ == [], d.summary()
    (layer,) = [t for t in d.demoted_ if t.candidate.name == 'wall_layer']
    assert 'does not hold at every load' in layer.check.reasons[-1]
    assert 'library lacks' in d.summary()


def test_a_real_wall_layer_and_a_real_weak_fan_hold_at_every_load(diagnosed, wb_setup):
    for effect, name in (('wall_boundary_layer', 'wall_layer'), ('weak_fan', 'fan_gain[HM2]')):
        d, _ = diagnosed(effect)
        (t,) = d.steps_
        assert t.candidate.name == name
        without = d._rebuild([])
        assert check_across_load(d.final_.model, t.candidate.label, t.candidate.null, d.train_,
                                 without.model, wb_setup.geometry) == ''
