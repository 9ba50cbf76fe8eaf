"""Hidden effects: one registry test runs every effect through the same checks, then each
effect is checked against the law its docstring states, then they compose."""
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from wind_shaper.sim import (HIDDEN_EFFECTS, BackgroundDraft, DeadBand, EffectError,
                             ElongatedFootprint, HiddenEffect, JetInteraction, SimulatedTunnel, Swirl,
                             TiltedFan, WallBoundaryLayer, WeakFan, make_effect)

CONFIG = Path(__file__).resolve().parents[3] / 'config' / 'sim.yaml'


def rot(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


# -- registry ----------------------------------------------------------------------------------------
@pytest.mark.parametrize('name', sorted(HIDDEN_EFFECTS))
def test_every_effect_builds_round_trips_and_changes_the_field(name, rig, tunnel):
    effect = make_effect(name)
    assert type(effect).__name__ in repr(effect) and effect.name == name
    assert make_effect(**effect.spec()) == effect
    assert make_effect(type(effect).__name__, **effect.truth()) == effect
    for key, (lo, hi) in effect.bounds.items():
        for bad in (lo - 1.0, hi + 1.0):
            with pytest.raises(EffectError, match=key):
                make_effect(name, **{**effect.truth(), key: bad})
    pwm = np.array([0.3, 0.6, 0.3, 0.6, 0.3, 0.6, 0.1])  # CCW-heavy, so swirl shows too
    if type(effect).recorded is not HiddenEffect.recorded:  # it changes the recording, not the field
        tunnel.apply(pwm)
        carried = tunnel.with_effects([effect])
        carried.apply(pwm)
        plain, late = (t.sweep(200, rng=np.random.default_rng(3)) for t in (tunnel, carried))
        np.testing.assert_allclose(late.forces, plain.forces)
        assert np.max(np.abs(late.positions - plain.positions)) > 0.005
        return
    if (type(effect).sensor_zero is not HiddenEffect.sensor_zero
            or type(effect).running is not HiddenEffect.running):  # a fault in time: sweeps only
        plain, carried = tunnel, tunnel.with_effects([effect])
        np.testing.assert_allclose(carried.true_field(pwm, rig.key_points),
                                   plain.true_field(pwm, rig.key_points))
        for t in (plain, carried):
            t.sweep(1000, rng=np.random.default_rng(2))   # 20 s of recording time first
            t.apply(pwm)
        a, b = (t.sweep(200, rng=np.random.default_rng(3)) for t in (plain, carried))
        assert np.max(np.abs(b.forces - a.forces)) > 0.02
        return
    changed = tunnel.with_effects([effect]).true_field(pwm, rig.key_points)
    assert np.max(np.abs(changed - tunnel.true_field(pwm, rig.key_points))) > 0.02


def test_make_effect_errors_name_the_choices():
    with pytest.raises(EffectError, match='weak_fan'):
        make_effect('gremlins')
    with pytest.raises(EffectError, match='gain'):
        make_effect('weak_fan', strength=0.5)


def test_effect_on_an_unknown_fan_is_refused_at_construction(rig):
    with pytest.raises(EffectError, match='XX9'):
        SimulatedTunnel(rig, effects=[WeakFan(fan='XX9')])


def test_config_examples_cover_every_effect():
    examples = re.findall(r'#\s*-\s*(\{name:.*?\})', CONFIG.read_text())
    names = {make_effect(**yaml.safe_load(e)).name for e in examples}
    assert names == set(HIDDEN_EFFECTS)


# -- each documented law ---------------------------------------------------------------------------
def test_weak_fan_scales_its_footprint_by_gain(perfect, rig, lone):
    weak = perfect.with_effects([WeakFan('HM2', 0.7)])
    hub = rig.fans.positions[rig.fans.index('HM2')][None]
    assert weak.true_field(lone('HM2'), hub)[0] == pytest.approx(0.7 * perfect.true_field(lone('HM2'), hub)[0])
    pwm = np.full(7, 0.5)
    drop = perfect.true_field(pwm, hub) - weak.true_field(pwm, hub)
    assert drop[0] == pytest.approx(0.3 * perfect.true_field(lone('HM2'), hub)[0])
    assert weak.thrust(pwm)[rig.fans.index('HM2')] == pytest.approx(0.7 * perfect.thrust(pwm)[3])


def test_swirl_rotates_a_lone_ccw_fan_by_gain(perfect, rig, lone):
    swirl = Swirl(gain=0.3)
    sim = perfect.with_effects([swirl])
    pwm = lone('HM1')  # CCW: theta = gain * (T - 0) / T = gain
    assert swirl.angle(sim.thrust(pwm), rig) == pytest.approx(0.3)
    pts = rig.key_points
    assert np.allclose(sim.point_field(pwm, pts @ rot(0.3).T), perfect.point_field(pwm, pts))
    hub = rig.fans.positions[rig.fans.index('HM1')]
    a = np.arctan2(hub[1], hub[0]) + np.linspace(-0.6, 0.9, 1501)
    ring = 0.25 * np.column_stack([np.cos(a), np.sin(a)])
    peak = a[np.argmax(sim.true_field(pwm, ring))] - np.arctan2(hub[1], hub[0])
    assert peak == pytest.approx(0.3, abs=0.01)  # plate-averaged peak also turns by theta
    assert swirl.angle(np.array([1, 1, 1, 1, 1, 1, 0.0]), rig) == 0.0  # balanced thrust: no turn
    assert Swirl(gain=0.3).angle(sim.thrust(lone('LM1')), rig) == pytest.approx(-0.3)


def test_wall_boundary_layer_follows_its_law_and_spares_the_core(perfect, rig):
    wall = perfect.with_effects([WallBoundaryLayer(thickness=0.06)])
    pwm = np.full(7, 0.5)
    R = rig.wall_radius
    pts = np.array([[0.0, 0.0], [0.2, 0.1], [0.0, R - 0.08], [0.6 * R, -0.7 * R], [0.0, R + 0.05]])
    r = np.hypot(*pts.T)
    law = np.where(r < R, 1 - np.exp(-(R - r) / 0.06), 0.0)
    base = perfect.point_field(pwm, pts)
    assert np.allclose(wall.point_field(pwm, pts), base * law)
    kp = rig.key_points
    ratio = wall.true_field(pwm, kp) / perfect.true_field(pwm, kp)
    rk = np.hypot(*kp.T)
    near_wall = rk >= R - 0.115  # the outer key-point rings
    assert near_wall.sum() > 10
    assert np.all(ratio[rk <= 0.05] > 0.97) and np.all(ratio[near_wall] < 0.9)
    square = perfect.with_effects([WallBoundaryLayer(0.06, shape='square')])
    corner = 0.9 * R  # outside the round wall, inside a square one of the same half-side
    assert square.point_field(pwm, np.array([[corner, corner]]))[0] > 0


def test_jet_interaction_fills_the_gap_between_neighbours(perfect, rig, lone):
    effect = JetInteraction(strength=0.3)
    assert len(effect.pairs(rig)) == 12  # 6 hexagon sides + 6 spokes to the centre
    sim = perfect.with_effects([effect])
    assert np.allclose(sim.true_field(lone('LM1'), rig.key_points),
                       perfect.true_field(lone('LM1'), rig.key_points))  # one fan: no pair
    pwm = np.zeros(7)
    pwm[[0, 1]] = 0.5  # LM1 and HM1
    t = perfect.thrust(pwm)
    mid = 0.5 * (rig.fans.positions[0] + rig.fans.positions[1])[None]
    extra = sim.point_field(pwm, mid) - perfect.point_field(pwm, mid)
    assert extra[0] == pytest.approx(0.3 * np.sqrt(t[0] * t[1]))


def test_dead_band_kills_small_commands_and_saturates(perfect, rig):
    band = perfect.with_effects([DeadBand(threshold=0.12, saturation=0.75)])
    kp = rig.key_points
    assert np.all(band.true_field(np.full(7, 0.10), kp) == 0)
    assert np.array_equal(band.true_field(np.full(7, 0.9), kp), band.true_field(np.full(7, 0.75), kp))
    u = 0.4
    eff = 0.75 * (u - 0.12) / (0.75 - 0.12)
    assert np.allclose(band.thrust(np.full(7, u)), perfect.thrust(np.full(7, eff)))


def test_tilted_fan_lands_displaced(perfect, rig, lone):
    sim = perfect.with_effects([TiltedFan('LM2', shift=(0.04, -0.02))])
    pts = rig.key_points
    assert np.allclose(sim.point_field(lone('LM2'), pts),
                       perfect.point_field(lone('LM2'), pts - np.array([0.04, -0.02])))


def test_elongated_footprint_stretches_along_and_squeezes_across(perfect, rig, lone):
    ratio, angle = 2.0, 0.5
    sim = perfect.with_effects([ElongatedFootprint('LM3', ratio=ratio, angle=angle)])
    hub = rig.fans.positions[rig.fans.index('LM3')]
    along, across = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    d = np.array([0.05, 0.1, 0.15])[:, None]
    pwm = lone('LM3')
    assert np.allclose(sim.point_field(pwm, hub + d * along),
                       perfect.point_field(pwm, hub + d * along / np.sqrt(ratio)))
    assert np.allclose(sim.point_field(pwm, hub + d * across),
                       perfect.point_field(pwm, hub + d * across * np.sqrt(ratio)))
    g = np.linspace(-0.6, 0.6, 241)
    xx, yy = np.meshgrid(g, g)
    grid = hub + np.column_stack([xx.ravel(), yy.ravel()])
    assert sim.point_field(pwm, grid).sum() == pytest.approx(perfect.point_field(pwm, grid).sum(), rel=1e-3)


def test_background_draft_adds_its_constant(perfect, rig):
    sim = perfect.with_effects([BackgroundDraft(force=0.3)])
    kp = rig.key_points
    for pwm in (np.zeros(7), np.full(7, 0.5)):
        assert np.allclose(sim.true_field(pwm, kp) - perfect.true_field(pwm, kp), 0.3)


# -- composition -----------------------------------------------------------------------------------
def test_effects_compose_in_pipeline_order_whatever_the_list_order(tunnel, rig):
    effects = [make_effect(n) for n in sorted(HIDDEN_EFFECTS)]
    pwm, kp = np.full(7, 0.5), rig.key_points
    a = tunnel.with_effects(effects).true_field(pwm, kp)
    b = tunnel.with_effects(effects[::-1]).true_field(pwm, kp)
    assert np.allclose(a, b) and np.all(np.isfinite(a))


def test_composed_laws(perfect, rig, lone):
    kp, pwm = rig.key_points, np.full(7, 0.5)
    weak_draft = perfect.with_effects([WeakFan('HM2', 0.5), BackgroundDraft(0.2)])
    weak = perfect.with_effects([WeakFan('HM2', 0.5)])
    assert np.allclose(weak_draft.true_field(pwm, kp), weak.true_field(pwm, kp) + 0.2)
    # the wall boundary layer slows the ambient draft too: F = (jets + draft) * factor
    both = perfect.with_effects([WallBoundaryLayer(0.06), BackgroundDraft(0.2)])
    p = np.array([[0.0, rig.wall_radius - 0.06]])
    factor = 1 - np.exp(-0.06 / 0.06)
    assert both.point_field(np.zeros(7), p)[0] == pytest.approx(0.2 * factor)
    # a dead band and a weak fan act on different stages and commute
    ab = perfect.with_effects([DeadBand(), WeakFan('LM1', 0.6)]).thrust(pwm)
    ba = perfect.with_effects([WeakFan('LM1', 0.6), DeadBand()]).thrust(pwm)
    assert np.allclose(ab, ba)


def test_effects_reach_calibration_and_sweeps(perfect, rig, lone):
    sim = perfect.with_effects([WeakFan('LM1', 0.5)])
    hub = rig.fans.positions[:1]
    sim.apply(lone('LM1'))
    assert sim.measure_at(hub)[0] == pytest.approx(sim.true_field(lone('LM1'), hub)[0])
    sweep = sim.sweep(200)
    assert np.allclose(sweep.forces, sim.true_field(sweep.pwm, sweep.positions))


def test_unequal_curves_give_every_fan_its_own_throttle_curve():
    from wind_shaper.sim import make_effect
    e = make_effect('unequal_curves', spread=0.3, seed=11)
    p = e.exponents(7)
    assert np.all(p > 0) and np.ptp(p) > 0.3 and np.all(np.abs(np.log(p)) <= 0.6 + 1e-12)
    u = np.full(7, 0.5)
    np.testing.assert_allclose(e.command(u, None), 0.5 ** p)
    np.testing.assert_allclose(e.command(np.ones(7), None), 1.0)   # full command is full thrust
    assert make_effect('unequal_curves', spread=0.0).command(u, None) == pytest.approx(u)


# -- the held-out physics (outside the library, written after the checks were set) ---------------
def test_jet_deflection_moves_edge_jets_inwards_only_with_the_central_fan_on(perfect, rig):
    from wind_shaper.sim import JetDeflection
    sim = perfect.with_effects([JetDeflection(pull=0.04, thrust_ref=3.0)])
    edge_only = np.array([0.5] * 6 + [0.0])
    assert np.allclose(sim.true_field(edge_only, rig.key_points),
                       perfect.true_field(edge_only, rig.key_points))
    on = np.full(7, 0.5)
    t_c = perfect.thrust(on)[6]
    state = sim.state(on)
    moved = np.concatenate([g.centres[g.fan < 6] for g in state.groups if (g.fan >= 0).any()])
    radii = np.hypot(*moved.T)
    assert np.allclose(radii, 0.25 - 0.04 * t_c / (t_c + 3.0))


def test_jet_pairing_pulls_alike_neighbours_together_and_leaves_a_lone_jet(perfect, rig):
    from wind_shaper.sim import JetPairing
    sim = perfect.with_effects([JetPairing(pull=0.04, thrust_ref=3.0)])
    ring = np.array([0.5] * 6 + [0.0])
    t = perfect.thrust(ring)[:6]                 # the two groups alternate round the ring
    lo, hi = t.min(), t.max()
    moved = np.concatenate([g.centres[g.fan < 6] for g in sim.state(ring).groups if (g.fan >= 0).any()])
    # each jet is pulled 0.04 (lo / hi) lo / (lo + 3) towards both neighbours, 60 degrees off
    # its inward radius: the tangential parts cancel, the inward ones add up to one pull
    assert np.allclose(np.hypot(*moved.T), 0.25 - 0.04 * (lo / hi) * lo / (lo + 3.0), atol=1e-6)
    lone = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.6])  # neighbours idle: nothing to pair with
    assert np.allclose(sim.true_field(lone, rig.key_points), perfect.true_field(lone, rig.key_points))


def test_coflow_carry_gives_a_jet_more_force_the_harder_the_others_run(perfect, rig, lone):
    from wind_shaper.sim import CoflowCarry
    sim = perfect.with_effects([CoflowCarry(carry=0.3, thrust_ref=3.0)])
    alone = lone('HM1', 0.6)                     # no co-flow: the jet as in still air
    assert np.allclose(sim.true_field(alone, rig.key_points), perfect.true_field(alone, rig.key_points))
    grid = np.stack(np.meshgrid(np.linspace(-0.6, 0.6, 121), np.linspace(-0.6, 0.6, 121)), -1).reshape(-1, 2)
    cell = (1.2 / 120) ** 2
    total = {}
    for label, tunnel in (('plain', perfect), ('carried', sim)):
        total[label] = float(np.sum(tunnel.point_field(np.full(7, 0.5), grid))) * cell
    t = perfect.thrust(np.full(7, 0.5))
    share = np.mean(0.3 * ((t.sum() - t) / 6) / ((t.sum() - t) / 6 + 3.0))
    # every jet carries 1 + c_j of its force: the field's integral grows by about the mean c
    assert total['carried'] / total['plain'] == pytest.approx(1 + share, rel=0.05)
    state = sim.state(np.full(7, 0.5))
    plain = perfect.state(np.full(7, 0.5))
    narrowed = [g.width[g.fan >= 0] / p.width[p.fan >= 0] for g, p in zip(state.groups, plain.groups)
                if (g.fan >= 0).any()]
    assert np.all(np.concatenate(narrowed) < 1.0)


def test_stall_dip_lowers_each_fan_by_its_own_depth_at_part_load(rig):
    from wind_shaper.sim import StallDip
    dip = StallDip(depth=0.2, at=0.35, width=0.08, seed=4)
    at = dip.command(np.full(7, 0.35), rig) / 0.35
    assert np.all((at >= 1 - 0.3 - 1e-9) & (at <= 1 - 0.1 + 1e-9)) and np.ptp(at) > 0.05
    far = dip.command(np.full(7, 0.8), rig)
    assert np.allclose(far, 0.8, atol=1e-6)
    assert not np.allclose(StallDip(seed=5).command(np.full(7, 0.35), rig), dip.command(np.full(7, 0.35), rig))


def test_esc_current_limit_flattens_each_fan_towards_its_own_ceiling(perfect, rig):
    from wind_shaper.sim import EscCurrentLimit
    limit = EscCurrentLimit(ceiling=4.0, spread=0.2, seed=7)
    sim = perfect.with_effects([limit])
    caps = limit.caps(7)
    assert np.all((caps >= 3.2) & (caps <= 4.8)) and np.ptp(caps) > 0.1
    low, high = np.full(7, 0.2), np.full(7, 0.65)
    # little changed where the thrust is far below the ceiling, much near and above it
    assert np.allclose(sim.thrust(low) / perfect.thrust(low), 1.0, atol=0.02)
    cut = sim.thrust(high) / perfect.thrust(high)
    assert np.all(cut < 0.85) and np.all(sim.thrust(high) < caps)
    # still rising: a stronger command never gives less thrust
    assert np.all(sim.thrust(np.full(7, 0.9)) > sim.thrust(high))
    with pytest.raises(EffectError, match='spread'):
        EscCurrentLimit(spread=1.5)


def test_diffuser_separation_takes_thrust_from_one_side_past_a_total(perfect, rig):
    from wind_shaper.sim import DiffuserSeparation
    sep = DiffuserSeparation(depth=0.3, onset=20.0, width=5.0, direction=30.0)
    sim = perfect.with_effects([sep])
    lean = sep.lean(rig)
    assert lean[rig.fans.index('HM1')] == pytest.approx(1.0) and lean[rig.fans.index('CM')] == 0.0
    assert np.all(lean[[rig.fans.index(f) for f in ('HM2', 'LM3', 'HM3')]] == 0.0)
    low, high = np.full(7, 0.2), np.full(7, 0.65)
    assert np.allclose(sim.thrust(low) / perfect.thrust(low), 1.0, atol=0.02)   # attached
    cut = 1 - sim.thrust(high) / perfect.thrust(high)
    facing = rig.fans.index('HM1')
    assert cut[facing] > 0.2 and np.allclose(cut, cut[facing] * lean)   # only the steep side
    # the other fans blowing harder separates the flow further: a coupling between fans
    alone = np.r_[0.0, 0.5, np.zeros(5)]
    others = np.r_[0.65, 0.5, np.full(5, 0.65)]
    assert sim.thrust(others)[facing] < 0.95 * perfect.thrust(others)[facing]
    assert sim.thrust(alone)[facing] == pytest.approx(perfect.thrust(alone)[facing], rel=0.02)
    with pytest.raises(EffectError, match='depth'):
        DiffuserSeparation(depth=1.5)


def test_side_inlet_starves_the_fans_far_from_it_more_as_the_flow_grows(perfect, rig):
    from wind_shaper.sim import SideInlet
    inlet = SideInlet(coupling=0.35, spread=0.8, direction=200.0)
    sim = perfect.with_effects([inlet])
    d = inlet.distance(rig)
    near, far = int(np.argmin(d)), int(np.argmax(d))
    assert d[rig.fans.index('CM')] == pytest.approx(0.0) and d[near] < -0.9 and d[far] > 0.9
    half = np.full(7, 0.5)
    run = inlet.command(half, rig)
    assert run[near] == pytest.approx(0.5 / (1 + 0.35 * 0.5 * (1 + 0.8 * d[near])))
    assert run[far] < run[rig.fans.index('CM')] < run[near] < 0.5
    # each fan's own slope: the far fan loses more of its thrust when the others open up
    alone, crowd = np.zeros(7), np.full(7, 0.6)
    alone[[near, far]] = 0.4
    crowd[[near, far]] = 0.4
    pair = [near, far]
    loss = 1 - sim.thrust(crowd)[pair] / perfect.thrust(crowd)[pair]
    loss_alone = 1 - sim.thrust(alone)[pair] / perfect.thrust(alone)[pair]
    assert loss[1] - loss_alone[1] > 1.5 * (loss[0] - loss_alone[0]) > 0
    with pytest.raises(EffectError, match='spread'):
        SideInlet(spread=2.0)


def test_jet_confinement_narrows_the_central_jet_as_the_edge_jets_blow(perfect, rig):
    from wind_shaper.sim import JetConfinement
    squeeze = JetConfinement(squeeze=0.25, thrust_ref=3.0)
    sim = perfect.with_effects([squeeze])
    assert squeeze.narrowing(3.0) == pytest.approx(1 / 1.125)
    centre = np.zeros((1, 2))
    ring = np.array([[0.32 * np.cos(a), 0.32 * np.sin(a)] for a in np.linspace(0, 2 * np.pi, 8, endpoint=False)])
    only = np.r_[np.zeros(6), 0.5]
    # the central fan alone: nothing hems it in
    assert sim.point_field(only, centre) == pytest.approx(perfect.point_field(only, centre))
    # with the edge fans blowing, taller over the middle and thinner at its rim than the sum
    crowd = np.r_[np.full(6, 0.5), 0.5]
    edge = np.r_[np.full(6, 0.5), 0.0]
    gain = sim.point_field(crowd, centre) - sim.point_field(edge, centre)
    plain = perfect.point_field(crowd, centre) - perfect.point_field(edge, centre)
    assert gain[0] > 1.1 * plain[0]
    assert np.all(sim.point_field(crowd, ring) - sim.point_field(edge, ring)
                  < perfect.point_field(crowd, ring) - perfect.point_field(edge, ring))
    with pytest.raises(EffectError, match='squeeze'):
        JetConfinement(squeeze=-1.0)


def test_flow_screen_spreads_a_share_of_every_jet_that_falls_as_the_flow_grows(perfect, rig):
    from wind_shaper.sim import FlowScreen
    screen = FlowScreen(share=0.4, thrust_ref=10.0, exponent=0.33)
    sim = perfect.with_effects([screen])
    assert screen.taken(0.0) == pytest.approx(0.4)
    assert screen.taken(20.0) == pytest.approx(0.4 * (10 / 30) ** 0.33)
    assert screen.taken(5.0) > screen.taken(30.0) > 0
    # the force is kept, only moved (hexagon fans: Gaussian footprints, whose force the screen
    # counts exactly): integrated over a square wider than the tunnel
    g = np.linspace(-0.9, 0.9, 181)
    grid = np.column_stack([a.ravel() for a in np.meshgrid(g, g)])
    cell = (g[1] - g[0]) ** 2
    hexagon = np.r_[np.full(6, 0.5), 0.0]
    assert (np.sum(sim.point_field(hexagon, grid)) * cell
            == pytest.approx(np.sum(perfect.point_field(hexagon, grid)) * cell, rel=0.03))
    # evener over the key points: a smaller spread about a mean that barely moves
    kp = rig.key_points
    plain, screened = perfect.true_field(hexagon, kp), sim.true_field(hexagon, kp)
    assert np.std(screened) < 0.8 * np.std(plain)
    # slow fans are evened out more: the screened field's spread against the plain one's
    slow, fast = np.full(7, 0.25), np.full(7, 0.65)
    evened = [np.std(sim.true_field(u, kp)) / np.std(perfect.true_field(u, kp)) for u in (slow, fast)]
    assert evened[0] < evened[1] < 1
    with pytest.raises(EffectError, match='share'):
        FlowScreen(share=1.5)


def test_esc_crosstalk_adds_a_share_of_the_source_command(perfect, rig, lone):
    from wind_shaper.sim import EscCrosstalk
    sim = perfect.with_effects([EscCrosstalk(fan='LM1', source='HM1', coupling=0.25)])
    pwm = lone('HM1', 0.8)
    expect = pwm.copy()
    expect[rig.fans.index('LM1')] = 0.2
    assert np.allclose(sim.true_field(pwm, rig.key_points), perfect.true_field(expect, rig.key_points))
    with pytest.raises(EffectError, match='XX9'):
        SimulatedTunnel(rig, effects=[EscCrosstalk(source='XX9')])


def test_wall_return_flow_follows_the_mean_thrust_not_the_local_jet(perfect, rig, lone):
    from wind_shaper.sim import WallReturnFlow
    sim = perfect.with_effects([WallReturnFlow(share=0.3, gap=0.03, width=0.04)])
    ring = np.array([[0.37 * np.cos(a), 0.37 * np.sin(a)] for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)])
    pwm = lone('HM1', 0.6)
    deficit = sim.point_field(pwm, ring) - perfect.point_field(pwm, ring)
    mean_thrust = perfect.thrust(pwm).mean()
    # as deep on the far side of the tunnel as beside the one running fan
    assert np.allclose(deficit, -0.3 * mean_thrust, rtol=0.05)
    assert np.allclose(sim.point_field(np.zeros(7), ring), 0.0)


def test_vane_ripple_and_jet_spreading_laws(perfect, rig, lone):
    from wind_shaper.sim import JetSpreading, VaneRipple
    ripple = VaneRipple(depth=0.15, wavelength=0.3, direction=0.0, phase=0.0)
    p = np.array([[0.0, 0.0], [0.15, 0.0]])
    pwm = np.full(7, 0.5)
    ratio = (perfect.with_effects([ripple]).point_field(pwm, p) / perfect.point_field(pwm, p))
    assert ratio == pytest.approx([1.15, 0.85])
    spread = perfect.with_effects([JetSpreading(exponent=0.12, thrust_ref=3.0)])
    strong, weak = lone('HM2', 0.8), lone('HM2', 0.2)
    for pwm in (strong, weak):
        t = perfect.thrust(pwm)[rig.fans.index('HM2')]
        widths = [g.width[g.fan == rig.fans.index('HM2')] for g in spread.state(pwm).groups]
        base = [g.width[g.fan == rig.fans.index('HM2')] for g in perfect.state(pwm).groups]
        w, w0 = np.concatenate(widths), np.concatenate(base)
        assert np.allclose(w / w0, np.clip((t / 3.0) ** 0.12, 0.6, 1.6))


# -- the second batch of held-out physics ------------------------------------------------------------
def test_hub_shadow_hollows_each_jet_core_and_spares_its_flanks(perfect, rig, lone):
    from wind_shaper.sim import HubShadow
    sim = perfect.with_effects([HubShadow(depth=0.3, core=0.45)])
    pwm = lone('HM2', 0.6)
    hub = rig.fans.positions[rig.fans.index('HM2')]
    w = [g.width[g.fan == rig.fans.index('HM2')] for g in perfect.state(pwm).groups]
    w = float(np.concatenate(w)[0])
    at = np.array([hub, hub + [1.5 * w, 0.0]])
    ratio = sim.point_field(pwm, at) / perfect.point_field(pwm, at)
    assert ratio[0] == pytest.approx(0.7, abs=0.02)      # the core loses depth x its peak
    assert ratio[1] > 0.97                                # the flank barely changes
    assert np.allclose(sim.point_field(np.zeros(7), at), 0.0)


def test_neighbour_starvation_is_local_to_a_fans_neighbours(perfect, rig):
    from wind_shaper.sim import NeighbourStarvation
    effect = NeighbourStarvation(coupling=0.3, thrust_ref=4.0)
    sim = perfect.with_effects([effect])
    names = list(rig.fans.names)
    lm1, hm1, hm2 = names.index('LM1'), names.index('HM1'), names.index('HM2')
    pwm = np.zeros(7)
    pwm[[lm1, hm2]] = 0.6     # LM1 and HM2 sit on opposite sides of HM1 on the hexagon
    t0 = perfect.thrust(pwm)
    t = sim.thrust(pwm)
    assert t[lm1] == pytest.approx(t0[lm1])  # its neighbours HM1, HM3 and CM idle
    pwm[hm1] = 0.6
    t0, t = perfect.thrust(pwm), sim.thrust(pwm)
    # LM1's neighbours: HM1, HM3 and CM; only HM1 runs
    assert t[lm1] == pytest.approx(t0[lm1] / (1 + 0.3 * (t0[hm1] / 3) / 4.0), rel=1e-6)


def test_coanda_attachment_moves_edge_jets_out_by_their_own_thrust(perfect, rig):
    from wind_shaper.sim import CoandaAttachment
    sim = perfect.with_effects([CoandaAttachment(pull=0.04, thrust_ref=4.0)])
    pwm = np.array([0.2, 0.8, 0.2, 0.8, 0.2, 0.8, 0.5])
    t = perfect.thrust(pwm)
    for g in sim.state(pwm).groups:
        for row in np.flatnonzero(g.fan >= 0):
            j = g.fan[row]
            r0 = np.hypot(*rig.fans.positions[j])
            expect = 0.0 if r0 < 1e-6 else r0 + 0.04 * t[j] / (t[j] + 4.0)
            assert np.hypot(*g.centres[row]) == pytest.approx(expect, abs=1e-9)


def test_wall_leak_follows_the_mean_thrust_not_the_local_jet(perfect, rig, lone):
    from wind_shaper.sim import WallLeak
    sim = perfect.with_effects([WallLeak(angle=200.0, share=0.5, spread=0.1)])
    gap = 0.40 * np.array([[np.cos(np.radians(200.0)), np.sin(np.radians(200.0))]])
    for name in ('HM2', 'LM1'):  # a fan near the gap, and one across the tunnel
        pwm = lone(name, 0.6)
        deficit = sim.point_field(pwm, gap) - perfect.point_field(pwm, gap)
        assert deficit[0] == pytest.approx(-0.5 * perfect.thrust(pwm).mean(), rel=1e-6)
    assert np.allclose(sim.point_field(np.zeros(7), gap), 0.0)


def test_drag_law_bends_the_plates_force_not_the_flow(perfect, rig):
    from wind_shaper.sim import DragLaw
    sim = perfect.with_effects([DragLaw(exponent=0.25, force_ref=2.0, floor=0.05)])
    pwm = np.array([0.2, 0.8, 0.2, 0.8, 0.2, 0.8, 0.5])
    plain = perfect.true_field(pwm, rig.key_points)
    expect = plain * (np.maximum(np.abs(plain), 0.05) / 2.0) ** -0.125
    np.testing.assert_allclose(sim.true_field(pwm, rig.key_points), expect, rtol=1e-12)
    np.testing.assert_allclose(sim.point_field(pwm, rig.key_points), perfect.point_field(pwm, rig.key_points))
    assert sim.true_field(np.zeros(7), rig.key_points) == pytest.approx(0.0, abs=1e-12)


def test_mocap_latency_pairs_each_force_with_an_earlier_position(perfect, rig):
    from wind_shaper.sim import MocapLatency
    pwm = np.full(7, 0.5)
    late = perfect.with_effects([MocapLatency(lag=0.04)])
    for t in (perfect, late):
        t.apply(pwm)
    a, b = (t.sweep(300, rng=np.random.default_rng(8)) for t in (perfect, late))
    np.testing.assert_allclose(b.forces, a.forces)       # the same flow, the same forces
    shift = round(0.04 * perfect.sample_rate_hz)         # 2 samples at 50 Hz
    np.testing.assert_allclose(b.positions[shift:], a.positions[:-shift], atol=1e-12)
    np.testing.assert_allclose(b.positions[:shift], a.positions[[0] * shift], atol=1e-12)


def test_ceiling_downwash_is_centred_and_follows_the_mean_thrust(perfect, rig, lone):
    from wind_shaper.sim import CeilingDownwash
    sim = perfect.with_effects([CeilingDownwash(share=0.12, spread=0.25)])
    axis, far = np.zeros((1, 2)), np.array([[0.0, 0.3]])
    for name in ('HM2', 'CM'):
        pwm = lone(name, 0.6)
        mean = perfect.thrust(pwm).mean()
        deficit = sim.point_field(pwm, axis) - perfect.point_field(pwm, axis)
        assert deficit[0] == pytest.approx(-0.12 * mean, rel=1e-6)
        deficit_far = sim.point_field(pwm, far) - perfect.point_field(pwm, far)
        assert deficit_far[0] == pytest.approx(-0.12 * mean * np.exp(-(0.3 / 0.25) ** 2), rel=1e-6)


def test_wall_reflection_mirrors_each_jet_in_the_wall(perfect, rig, lone):
    from wind_shaper.sim import WallReflection
    sim = perfect.with_effects([WallReflection(share=0.6)])
    hm2 = rig.fans.index('HM2')
    hub = rig.fans.positions[hm2]
    r = np.hypot(*hub)
    image = hub * (2 * rig.wall_radius - r) / r
    pwm = lone('HM2', 0.6)
    # 10 cm beyond the hub the field gains 0.6 x the jet's own force as far from its hub as
    # this point is from the image
    p = hub * (r + 0.1) / r
    mirrored = hub + (p - image)
    extra = sim.point_field(pwm, p[None]) - perfect.point_field(pwm, p[None])
    assert extra[0] == pytest.approx(0.6 * perfect.point_field(pwm, mirrored[None])[0], rel=1e-6)
    # the central fan has no image, and nothing is added with every fan off
    cm = lone('CM', 0.6)
    np.testing.assert_allclose(sim.point_field(cm, rig.key_points), perfect.point_field(cm, rig.key_points))
    np.testing.assert_allclose(sim.point_field(np.zeros(7), rig.key_points), 0.0, atol=1e-12)
