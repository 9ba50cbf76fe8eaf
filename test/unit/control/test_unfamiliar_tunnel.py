"""Shaping a tunnel the prior does not describe: the warm start must not trap the loop, and a run
whose tunnel changes must learn again.

The tunnels here carry physics the prior's per-fan corrections cannot absorb (merging jets, swirl
with the CW/CCW balance, a thin wall layer, a crosstalk between two fans' outputs); the prior is
calibrated on the tunnel with the paper's held-plate batch, as a lab would.
"""
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import least_squares

from wind_shaper.app import Setup, calibrate
from wind_shaper.control import ShapingLoop
from wind_shaper.control.chain import chain_start, contradiction
from wind_shaper.control.warm_start import WarmStart, warm_start
from wind_shaper.sim import effects_from_config

#: merging jets and a 4 cm wall layer beside a weak fan and swirl: calibrated on single fans, the
#: prior puts the soaring profile on the central fan's ring alone, a basin the tunnel does not
#: share (its optimum has the six edge fans near 50 % and the central fan off).
HARSH = [{'name': 'weak_fan', 'fan': 'HM2', 'gain': 0.75}, {'name': 'swirl', 'gain': 0.5},
         {'name': 'merging_jets', 'strength': 0.5, 'exponent': 0.75},
         {'name': 'wall_boundary_layer', 'thickness': 0.04}]


def _best_error(sim, kp, target, on, bounds, starts):
    """The lowest true-field MSE [N^2] the fans can reach, from a few starts."""
    best = np.inf
    for x0 in starts:
        def f(x):
            U = np.zeros(len(on))
            U[on] = x
            return sim.true_field(U, kp) - target
        sol = least_squares(f, np.asarray(x0)[on], bounds=(bounds.u_min, bounds.u_max),
                            diff_step=1e-4, max_nfev=200)
        best = min(best, float(np.mean(sol.fun ** 2)))
    return best


@pytest.fixture(scope='module')
def harsh(tmp_path_factory):
    setup = Setup.load()
    effects = list(effects_from_config(HARSH))
    fit = calibrate(setup.make_sim(seed=0, effects=effects), setup.geometry.fans)
    return setup, effects, fit.model, fit.rmse


def test_a_prior_with_the_wrong_optimum_does_not_trap_the_soaring_profile(harsh):
    setup, effects, prior, model_error = harsh
    kp, on, bounds = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    target = setup.make_target('parabolic').values(kp)
    sim = setup.make_sim(seed=2, effects=effects)
    warm = warm_start(prior, kp, target, bounds, on, model_error=model_error)
    zeta = _best_error(sim, kp, target, on, bounds, [np.full(len(on), 0.5), warm.U])
    assert np.mean((sim.true_field(warm.U, kp) - target) ** 2) > 1.5 * zeta  # the trap is there
    loop = ShapingLoop.from_settings(sim, prior, target, setup.shaping, model_error=model_error,
                                     truth=lambda U: sim.true_field(U, kp))
    history = loop.run(6)
    first = history[0].info
    assert first['warm_start']['check']['restart'] and 'starts again' in first['warm_start']['check_text']
    assert np.allclose(history[1].pwm[on], 0.5)   # the wider start
    # before: 1.96 x the best error at every iteration (the loop stayed in the prior's basin)
    assert history[-1].true_error <= 1.1 * zeta


def test_a_prior_that_is_right_keeps_its_warm_start(harsh):
    setup = Setup.load()
    kp = setup.geometry.key_points
    sim = setup.make_sim(seed=1)
    loop = ShapingLoop.from_settings(sim, setup.load_model(), setup.make_target('parabolic').values(kp),
                                     setup.shaping, model_error=setup.model_error())
    history = loop.run(2)
    assert not history[0].info['warm_start']['check']['restart']
    assert 'restart_next' not in history[0].info
    assert not any(r.info.get('relearned') for r in history)


def test_a_run_whose_tunnel_changes_learns_it_again():
    """Three iterations on a tunnel with a weak fan and an ESC crosstalk, then the same run goes on
    on the tunnel without them (a fan repaired between iterations)."""
    setup = Setup.load()
    kp = setup.geometry.key_points
    prior, target = setup.load_model(), setup.make_target('parabolic').values(kp)
    before = setup.make_sim(seed=0, effects=list(effects_from_config(
        [{'name': 'weak_fan', 'fan': 'HM2', 'gain': 0.6},
         {'name': 'esc_crosstalk', 'fan': 'LM1', 'source': 'HM1', 'coupling': 0.25}])))
    after = setup.make_sim(seed=50)

    def rmse(U):
        return float(np.sqrt(np.mean((after.true_field(U, kp) - target) ** 2)))
    loop = ShapingLoop.from_settings(before, prior, target, setup.shaping,
                                     model_error=setup.model_error())
    for _ in range(3):
        loop.iterate()
    loop.tunnel = after
    changed = [loop.iterate() for _ in range(4)]
    assert any(r.info.get('relearned') for r in changed)
    fresh = ShapingLoop.from_settings(setup.make_sim(seed=51), prior, target, setup.shaping,
                                      model_error=setup.model_error())
    floor = min(rmse(fresh.iterate().pwm) for _ in range(4))
    # before: 0.94-1.2 N three to six iterations after the change, against a floor of 0.69 N
    assert rmse(loop.U) <= 1.05 * floor


def test_the_chain_starts_after_a_restart_and_at_a_relearned_map():
    assert chain_start([{}, {}, {}]) == (0, 0)
    assert chain_start([{'restart_next': {}}, {}, {}]) == (1, 0)
    assert chain_start([{}, {'relearned': {'miss_N': 1}}, {}]) == (1, 1)
    assert chain_start([{'restart_next': {}}, {}, {'relearned': {}}, {}]) == (2, 2)
    assert chain_start([{'restart_next': {}}]) == (0, 0)   # nothing after it yet


def _maps(miss, std=0.05, n=50):
    U0, U1 = np.full(3, 0.4), np.full(3, 0.42)
    r0 = np.linspace(-0.2, 0.2, n)
    return [(U0, r0, np.full(n, std), {}), (U1, r0 + 0.1 + miss, np.full(n, std), {})]


def test_a_map_that_misses_the_predicted_change_by_far_more_than_noise_contradicts():
    def model(U):
        return np.full(50, 5.0 * float(np.mean(U))), None   # predicts +0.1 N for the 0.02 step
    agree = contradiction(_maps(0.0), 0, model, floor=0.05)
    assert not agree.contradicts and agree.miss == pytest.approx(0.0, abs=1e-9)
    noisy = contradiction(_maps(0.2), 0, model, floor=0.05)     # 0.2 N: within 4 x 0.1 + 0.1
    assert not noisy.contradicts
    changed = contradiction(_maps(0.8), 0, model, floor=0.05)
    assert changed.contradicts and changed.against == 0 and 'learns again' in changed.text()
    assert contradiction(_maps(0.8)[:1], 0, model, floor=0.05) is None


def test_the_restart_needs_the_prior_calibration_error():
    setup = Setup.load()
    kp, on, b = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    target = setup.make_target('uniform').values(kp)
    std = np.full(len(kp), 0.05)
    ws = warm_start(setup.load_model(), kp, target, b, on, model_error=0.1)
    far = ws.compare(ws.predicted + 0.8, std)
    assert far.restart and far.measured_mse > far.allowed_mse
    U, extra = ws.next_commands(far, np.full(len(on), 0.3))
    assert np.allclose(U[on], 0.5) and 'restart_next' in extra
    near = ws.compare(ws.predicted + 0.05, std)
    assert not near.restart and ws.next_commands(near, np.full(len(on), 0.3))[1] == {}
    unknown = warm_start(setup.load_model(), kp, target, b, on)   # no calibration error
    assert not unknown.compare(unknown.predicted + 0.8, std).restart

    # the restart is kept only when the first update sees no step that closes the gap
    stuck = WarmStart.after_first_step(far, 0.9 * far.measured_mse)
    assert stuck.restart and stuck.step_share == pytest.approx(0.9)
    way_out = WarmStart.after_first_step(far, 0.1 * far.measured_mse)
    assert not way_out.restart and way_out.restart_declined and 'steps from here' in way_out.text()
    assert ws.next_commands(way_out, np.full(len(on), 0.3))[1] == {}
    assert WarmStart.after_first_step(far, None) == far          # a rule that predicts nothing


def test_a_prior_of_weaker_fans_steps_from_its_first_sweep_instead_of_starting_again():
    """The shipped prior on the simulated tunnel with every fan at 75 % thrust, uniform profile:
    the prior's optimum runs only the central fan, the first sweep's error is far beyond the
    promise, but the corrected model sees the step that closes it; starting again from every fan
    at 0.5 would spend the second sweep at 6 x the first sweep's error."""
    from wind_shaper.app import shaping_loop_on_sim
    from wind_shaper.sim import make_effect
    setup = Setup.load()
    sim = setup.make_sim(seed=0, effects=[make_effect('weak_fan', fan=f, gain=0.75)
                                          for f in setup.geometry.fans.names])
    loop, _ = shaping_loop_on_sim(setup, 'uniform', seed=0, sim=sim)
    history = loop.run(1)
    check = history[0].info['warm_start']['check']
    assert check['restart_declined'] and not check['restart'], check
    assert check['measured_mse_N2'] > check['allowed_mse_N2'] and check['step_share'] < 0.5
    assert 'restart_next' not in history[0].info
    # measured: 0.55 N^2 at the warm start, 0.11 after the step (3.47 at the wider start)
    assert history[1].true_error < 0.5 * history[0].true_error


def _loop(setup, sim, prior, target, model_error, **rule):
    s = setup.shaping
    return ShapingLoop(sim, prior, target, s.make_rule(**rule), s.make_estimator(prior), u0='warm',
                       n_samples=s.samples_per_sweep, sweep_length=s.make_sweep_length(),
                       fan_settle_s=s.fan_settle_s, model_error=model_error)


def test_a_load_slope_learns_a_starved_inlet_in_two_steps():
    """A shared inlet starves every fan the harder all of them run (U / (1 + c mean U)); the
    per-fan gains fit one level for maps at different loads. With the load slope the second
    update lands near the optimum (seeds 2-5: 1.003-1.007 x the best error after the second
    update, 1.16 without)."""
    setup = Setup.load()
    effects = list(effects_from_config([{'name': 'plenum_starvation'}]))
    fit = calibrate(setup.make_sim(seed=0, effects=effects), setup.geometry.fans)
    kp, on, bounds = setup.geometry.key_points, setup.geometry.fans.enabled, setup.shaping.bounds
    target = setup.make_target('parabolic').values(kp)
    sim = setup.make_sim(seed=2, effects=effects)
    zeta = _best_error(sim, kp, target, on, bounds, [np.full(len(on), 0.5)])
    after = {}
    for load_sd in (0.0, 0.5):
        loop = _loop(setup, setup.make_sim(seed=2, effects=effects), fit.model, target, fit.rmse,
                     load_sd=load_sd)
        records = [loop.iterate(update=True) for _ in range(2)]
        after[load_sd] = float(np.mean((sim.true_field(records[-1].next_pwm, kp) - target) ** 2)) / zeta
    assert after[0.5] < 1.05 and after[0.5] < after[0.0], after


#: jets in a co-flow that carry more the harder the others run, a stall dip in every fan's
#: curve, a weak fan and a tilted one: the prior commissioned on six designed sweeps puts the
#: uniform profile's first step far off (the benchmark's `coflow + stall + weak`)
COFLOW = [{'name': 'coflow_carry', 'carry': 0.3, 'thrust_ref': 3.0},
          {'name': 'stall_dip', 'depth': 0.2, 'at': 0.45, 'width': 0.1, 'seed': 5},
          {'name': 'weak_fan', 'fan': 'LM1', 'gain': 0.85},
          {'name': 'tilted_fan', 'fan': 'HM1', 'shift': [0.02, -0.03]}]


def _commissioned(effect_specs, design_spec: str = 'lhs:6+level', without: tuple = ()):
    """(setup, effects, calibration, commissioning maps): the prior commissioned on the tunnel
    with ``effect_specs`` from the designed sweeps ``design_spec``, as the commissioning guide
    says; ``without``: labels of the design's sweeps left out."""
    from wind_shaper.experiment.design import make_design
    from wind_shaper.workbench.calibrate import calibrate_default_prior, commissioning_maps
    from wind_shaper.workbench.data import from_sim
    setup = Setup.load()
    shaping, effects = setup.shaping, list(effects_from_config(effect_specs))
    design = make_design(design_spec, setup.geometry.fans, shaping.u_min, shaping.u_max, seed=0)
    kept = [i for i, label in enumerate(design.labels) if label not in without]
    data = from_sim(setup.make_sim(seed=0, effects=effects), design.commands[kept],
                    n_samples=shaping.samples_per_sweep)
    cal = calibrate_default_prior(data, setup.geometry.fans)
    return setup, effects, cal, commissioning_maps(data, shaping.make_estimator(cal.model),
                                                   setup.geometry.key_points)


def _run(commissioned, target, seed: int, overrides: dict, iterations: int):
    """A shaping run on a tunnel from ``_commissioned`` with ``overrides`` of the update rule:
    (its records, the true error [N^2] at the commands its last update sends)."""
    setup, effects, cal, maps = commissioned
    loop = ShapingLoop.from_settings(setup.make_sim(seed=seed, effects=effects), cal.model, target,
                                     setup.shaping, model_error=cal.heldout_rmse, prior_maps=maps,
                                     rule_overrides=overrides)
    records = [loop.iterate() for _ in range(iterations)]
    truth = setup.make_sim(seed=seed, effects=effects).true_field(records[-1].next_pwm, setup.geometry.key_points)
    return records, float(np.mean((truth - target) ** 2))


@pytest.fixture(scope='module')
def coflow():
    """The co-flow tunnel's prior commissioned from designed sweeps, and their field maps."""
    return _commissioned(COFLOW, 'lhs:6')


def test_the_commissioning_maps_put_the_first_step_on_an_unfamiliar_tunnel_near_the_optimum(coflow):
    """Fitted on the run's one map (at the prior's optimum) the first step more than doubles the
    error; fitted on that map and the commissioning's four maps with fans running, it halves it.
    Later steps fit only the maps near their base, each less the farther it is."""
    setup, effects, cal, maps = coflow
    kp = setup.geometry.key_points
    assert len(maps) == 4   # the design's two sweeps with every fan off left out
    sim = setup.make_sim(seed=1, effects=effects)
    target = setup.make_target('uniform').values(kp)

    def error(U):
        return float(np.mean((sim.true_field(U, kp) - target) ** 2))
    runs = {}
    for name, given in (('with', maps), ('without', ())):
        loop = ShapingLoop.from_settings(sim, cal.model, target, setup.shaping,
                                         model_error=cal.heldout_rmse, prior_maps=given)
        runs[name] = [loop.iterate(), loop.iterate()]
    first = runs['with'][0]
    assert first.info['commissioning_maps'] == 4 and runs['without'][0].info['commissioning_maps'] == 0
    second = runs['with'][1].info
    assert 0 < second['commissioning_weight'] < first.info['commissioning_weight'] == pytest.approx(4.0)
    start = error(first.pwm)
    # measured: 0.53 N^2 at the warm start; 0.23 with the maps, 1.09 without
    assert error(first.next_pwm) < 0.6 * start < 0.6 * error(runs['without'][0].next_pwm)


def test_a_first_sweep_that_contradicts_the_prior_drops_the_commissioning_maps(coflow):
    from dataclasses import replace as _replace

    from wind_shaper.control.warm_start import PredictionCheck, first_step_rule
    setup = coflow[0]
    rule = setup.shaping.make_rule()
    agree = PredictionCheck(0.1, 0.1, 1.0, False)
    assert first_step_rule(rule, agree).commissioning_weight == rule.commissioning_weight > 0
    off = first_step_rule(rule, _replace(agree, ratio=5.0, mismatch=True))
    assert off.commissioning_weight == 0 and off.radius == rule.radius


def test_commissioning_maps_of_another_tunnel_layout_are_refused(coflow):
    from dataclasses import replace as _replace

    from wind_shaper.core.errors import ConfigError
    setup, effects, cal, maps = coflow
    kp = setup.geometry.key_points
    short = (_replace(maps[0], mean=maps[0].mean[:-3]),)
    with pytest.raises(ConfigError, match='key points'):
        ShapingLoop.from_settings(setup.make_sim(seed=0), cal.model, np.zeros(len(kp)),
                                  setup.shaping, prior_maps=short)


def test_later_updates_weigh_each_commissioning_map_by_its_distance_from_the_base():
    """First update: every map at full weight. Later ones: exp(-(d / reach)^2), d the largest
    command difference from the base; none after a mismatched first sweep, after relearning,
    or with reach 0."""
    from dataclasses import replace as _replace

    from wind_shaper.control import AdaptiveUpdate
    from wind_shaper.control.update import PastIteration, UpdateInput
    rule = AdaptiveUpdate(commissioning_weight=1.0, commissioning_reach=0.15)
    base = np.full(7, 0.3)
    maps = tuple(PastIteration(base + d, np.zeros(3)) for d in (0.0, 0.15, 0.3, -0.45))
    first = UpdateInput(0, base, np.zeros(3), None, np.ones(7, bool), target=np.zeros(3), prior_maps=maps)
    assert rule._commissioning_weights(first, (), 0, None, base) == [1.0] * 4
    past = (PastIteration(base, np.zeros(3), info={'warm_start': {'check': {'mismatch': False}}}),)
    later = _replace(first, k=1, history=past)
    w = rule._commissioning_weights(later, past, 0, None, base)
    assert w == pytest.approx([1.0, np.exp(-1.0), np.exp(-4.0), np.exp(-9.0)])
    mismatched = (PastIteration(base, np.zeros(3), info={'warm_start': {'check': {'mismatch': True}}}),)
    assert rule._commissioning_weights(later, mismatched, 0, None, base) == [0.0] * 4
    assert rule._commissioning_weights(later, past, 1, None, base) == [0.0] * 4      # relearned
    assert AdaptiveUpdate(commissioning_reach=0.0)._commissioning_weights(later, past, 0, None, base) == [0.0] * 4
    assert rule._commissioning_weights(_replace(first, target=None), (), 0, None, base) == [0.0] * 4


def test_a_run_of_the_default_length_keeps_what_its_first_maps_taught():
    """A starved inlet: three maps at different loads teach the load slope, then eight sweeps
    near one operating point. The shipped rule still fits the slope from the first maps at the
    eleventh update (a window of 8 maps dropped them and the slope fell back to its prior, 0,
    moving the next step by 0.03 PWM on nothing the sweeps had shown)."""
    from wind_shaper.control.update import PastIteration, UpdateInput
    setup = Setup.load()
    sim = setup.make_sim(seed=0, effects=list(effects_from_config([{'name': 'plenum_starvation'}])))
    kp, on = setup.geometry.key_points, setup.geometry.fans.enabled
    target = setup.make_target('uniform').values(kp)
    rng = np.random.default_rng(0)
    operating = np.r_[np.full(6, 0.2), 0.55]
    commands = ([np.full(7, 0.5), operating, np.r_[np.zeros(6), 0.5]]
                + [operating + rng.uniform(-0.01, 0.01, 7) for _ in range(8)])
    assert len(commands) <= setup.shaping.iterations     # a run of the default length
    std = np.full(len(kp), 0.04)
    maps = [PastIteration(U, sim.true_field(U, kp) + rng.normal(0, 0.04, len(kp)), std) for U in commands]
    rule = setup.shaping.make_rule()

    def step(n):
        last = maps[n - 1]
        return rule.step(UpdateInput(n - 1, last.U, target - last.mean, None, on, std=std,
                                     model=setup.load_model(), key_points=kp, target=target,
                                     history=tuple(maps[:n - 1])))
    early, late = step(4), step(len(maps))
    assert early.info['load_slope'] < -0.5          # the inlet's starving is learned ...
    assert late.info['load_slope'] == pytest.approx(early.info['load_slope'], abs=0.15)   # ... and kept
    assert np.max(np.abs(late.U_next - early.U_next)) < 0.015


def test_what_the_commissioning_taught_of_each_fan_is_the_prior_of_the_later_fits():
    """A central fan 40 % weaker than the prior says, idle in the run's maps so far: the
    commissioning's maps showed it running. With what they taught kept as the prior of the
    second update's fit (``commissioning_anchor``), the step lands nearer the optimum than with
    the prior's own gains (the far commissioning maps have faded from that fit by then). The
    step is longer than the reach, so ``commissioning_landing`` is held off: solved again with
    the maps near its end, it lands as near without the anchor (0.131 against 0.129 N^2)."""
    from wind_shaper.control import AdaptiveUpdate
    from wind_shaper.control.update import PastIteration, UpdateInput
    setup = Setup.load()
    sim = setup.make_sim(seed=0, effects=list(effects_from_config([{'name': 'weak_fan', 'fan': 'CM', 'gain': 0.6}])))
    kp, on, model = setup.geometry.key_points, setup.geometry.fans.enabled, setup.load_model()
    target = setup.make_target('uniform').values(kp)
    std = np.full(len(kp), 0.03)

    def error(U):
        return float(np.mean((sim.true_field(U, kp) - target) ** 2))
    errors = {False: [], True: []}
    for seed in range(3):
        rng = np.random.default_rng(seed)

        def measure(U, info=None):
            return PastIteration(np.asarray(U, float), sim.true_field(U, kp) + rng.normal(0, 0.03, len(kp)),
                                 std, info=info or {})
        commissioning = tuple(measure(rng.uniform(0.15, 0.6, 7)) for _ in range(5))
        start = np.r_[np.full(6, 0.4), 0.0]       # the warm start idles the central fan
        first = measure(start, {'warm_start': {'check': {'mismatch': False}}})
        now = measure(start + np.r_[rng.uniform(-0.01, 0.01, 6), 0.0])
        for anchor in (False, True):
            step = AdaptiveUpdate(commissioning_anchor=anchor, commissioning_landing=False).step(
                UpdateInput(1, now.U, target - now.mean, None, on, std=std, model=model, key_points=kp,
                            target=target, history=(first,), prior_maps=commissioning))
            errors[anchor].append(error(step.U_next))
    # measured: 0.130 / 0.129 / 0.133 N^2 against 0.330 / 0.186 / 0.163
    assert all(a < p for a, p in zip(errors[True], errors[False]))
    assert np.mean(errors[True]) < 0.8 * np.mean(errors[False])


def test_the_commissionings_level_map_is_one_of_the_runs_maps_but_never_its_base():
    """The level sweep's map (every fan at one command) is fitted in every update as one of the
    run's maps, however far from the base; after the first update it is never stepped from, even
    where it is the best map (the first may step from it: ``first_step_from_level``), and it goes
    with the other commissioning maps once the tunnel is not the one commissioned."""
    from dataclasses import replace as _replace

    from wind_shaper.control.adaptive import is_level
    from wind_shaper.control.update import PastIteration, UpdateInput
    setup = Setup.load()
    sim = setup.make_sim(seed=0, effects=list(effects_from_config([{'name': 'weak_fan', 'fan': 'CM', 'gain': 0.6}])))
    kp, on, model = setup.geometry.key_points, setup.geometry.fans.enabled, setup.load_model()
    target = setup.make_target('uniform').values(kp)
    std = np.full(len(kp), 0.03)
    rng = np.random.default_rng(0)

    def measure(U, info=None):
        return PastIteration(np.asarray(U, float), sim.true_field(U, kp) + rng.normal(0, 0.03, len(kp)),
                             std, info=info or {})
    designed = tuple(measure(rng.uniform(0.05, 0.6, 7)) for _ in range(3))
    level = _replace(measure(np.full(7, 0.325)), mean=target.copy())   # the best map there is
    start = np.r_[np.full(6, 0.4), 0.05]
    first = measure(start, {'warm_start': {'check': {'mismatch': False}}})
    now = measure(start + np.r_[rng.uniform(-0.01, 0.01, 6), 0.0])
    inp = UpdateInput(1, now.U, target - now.mean, None, on, std=std, model=model, key_points=kp,
                      target=target, history=(first,), prior_maps=designed + (level,))
    rule = setup.shaping.make_rule()
    step = rule.step(inp)
    assert step.info['level_map'] and step.info['base_k'] != 0   # the run's maps follow it
    assert step.info['commissioning_maps'] <= len(designed)       # not among the faded ones
    without = setup.shaping.make_rule(level_map=False).step(inp)
    assert not without.info['level_map'] and np.max(np.abs(without.U_next - step.U_next)) > 0.005
    mismatched = (_replace(first, info={'warm_start': {'check': {'mismatch': True}}}),)
    assert not rule.step(_replace(inp, history=mismatched)).info['level_map']
    assert not rule.step(_replace(inp, prior_maps=designed)).info['level_map']
    first_after_mismatch = _replace(rule, commissioning_weight=0.0)      # ``first_step_rule``
    assert not first_after_mismatch.step(_replace(inp, k=0, history=())).info['level_map']
    assert is_level(np.r_[np.full(6, 0.3), 0.0], np.r_[np.ones(6, bool), False])
    assert not is_level(np.zeros(7), on) and not is_level(np.r_[np.full(6, 0.3), 0.31], on)


#: a sagging shared supply, a recirculation bubble over the middle, a tilted and a weak fan
#: (the benchmark's `supply sag + core + tilt`)
SAG = [{'name': 'supply_sag', 'sag': 0.3}, {'name': 'recirculation_core', 'share': 0.4},
       {'name': 'tilted_fan', 'fan': 'LM2', 'shift': [0.04, 0.0]},
       {'name': 'weak_fan', 'fan': 'LM3', 'gain': 0.85}]


def test_the_level_sweep_frees_a_run_that_settles_above_the_optimum():
    """The soaring profile on a sagging supply, the prior commissioned from `lhs:6+level`: after
    the first step the run's maps sit within a few hundredths of PWM of each other and the
    corrected model sees no step worth taking, 2-3 % above where the level map, kept among the
    run's maps, lets the steps go."""
    setup, effects, cal, maps = _commissioned(SAG)
    kp = setup.geometry.key_points
    target = setup.make_target('parabolic').values(kp)
    after = {}
    for seed in (2, 3):
        for level in (False, True):
            records, error = _run((setup, effects, cal, maps), target, seed, {'level_map': level}, 4)
            assert records[-1].info['level_map'] == level
            after[seed, level] = error
    # measured [N^2] (seeds 2, 3): 0.4663 / 0.4623 without, 0.4538 / 0.4503 with
    assert all(after[s, True] < after[s, False] for s in (2, 3)), after
    assert after[2, True] + after[3, True] < 0.985 * (after[2, False] + after[3, False]), after


#: a mesh screen spreading a share of every jet over the section, a warm wall's tilt and a
#: starved inlet: the per-fan fit, without a term for either, bends the gains and the load slope
#: to hold them, and the second step mispredicts how the field's level follows the edge fans
SCREEN_WARM = [{'name': 'flow_screen', 'share': 0.3},
               {'name': 'thermal_gradient', 'slope': 0.15, 'direction': 40.0},
               {'name': 'plenum_starvation', 'coupling': 0.5}]


def test_the_spread_and_the_tilt_keep_the_second_step_on_a_screened_warm_tunnel():
    """The uniform profile on that tunnel, its prior commissioned from `lhs:6+level`: with the
    fit's spread share and plane (the shipped settings) the commands after the second update
    give 0.0637 / 0.0643 N^2 (seeds 2, 3), without them 0.0652 / 0.0682. (With the middle level
    sweep alone, before the low one joined it, without them 0.1006 / 0.0710: the low level map
    shows most of what the terms hold.)"""
    setup, effects, cal, maps = _commissioned(SCREEN_WARM)
    shaping, kp = setup.shaping, setup.geometry.key_points
    assert shaping.make_rule().spread_sd > 0 and shaping.make_rule().tilt_sd > 0
    target = setup.make_target('uniform').values(kp)
    after = {}
    for seed in (2, 3):
        for terms in (True, False):
            overrides = {} if terms else {'spread_sd': 0.0, 'tilt_sd': 0.0}
            after[seed, terms] = _run((setup, effects, cal, maps), target, seed, overrides, 2)[1]
    assert all(after[s, True] < after[s, False] for s in (2, 3)), after
    assert after[2, True] + after[3, True] < 0.975 * (after[2, False] + after[3, False]), after


#: fans whose curves differ from each other, jets in a co-flow that carry more the harder the
#: others run, and jets that pull towards their neighbours: written for the low level sweep's
#: test, not drawn, and not among the benchmark's tunnels
UNEQUAL_COFLOW = [{'name': 'unequal_curves', 'spread': 0.3, 'seed': 17},
                  {'name': 'coflow_carry', 'carry': 0.35},
                  {'name': 'jet_pairing', 'pull': 0.03}]


def test_the_low_level_sweep_brings_the_third_sweep_nearer_the_optimum():
    """The prior commissioned from `lhs:6+level` (the middle and the low level sweep) against the
    same design without its low level sweep (the commissioning before it joined): the run's maps
    sit where the optimum keeps many fans low, which the middle level map does not show. The
    third sweep [N^2], seeds 2 / 3, measured: uniform 0.0884 / 0.0965 against 0.1226 / 0.1315,
    Gaussian 0.0592 / 0.0642 against 0.0811 / 0.0710. Both with ``off_margin`` 0, as when the
    low level sweep joined: switching a fan off only for a clear gain takes the run without the
    low level map most of the way on the uniform profile (0.0958 / 0.0969), the same fans' low
    end seen by another route."""
    from wind_shaper.experiment.design import make_design
    setup = Setup.load()
    shaping, kp = setup.shaping, setup.geometry.key_points
    design = make_design('lhs:6+level', setup.geometry.fans, shaping.u_min, shaping.u_max, seed=0)
    assert list(design.labels[-3:-1]) == ['level (middle)', 'level (low)']
    third = {}
    for low in (True, False):
        _, effects, cal, maps = _commissioned(UNEQUAL_COFLOW, without=() if low else ('level (low)',))
        for name in ('uniform', 'gaussian@LM1'):
            target = setup.make_target(name).values(kp)
            for seed in (2, 3):
                records, error = _run((setup, effects, cal, maps), target, seed, {'off_margin': 0.0}, 2)
                assert records[-1].info['level_maps'] == (2 if low else 1)
                third[name, seed, low] = error
    for name in ('uniform', 'gaussian@LM1'):
        assert all(third[name, s, True] < third[name, s, False] for s in (2, 3)), third
        assert third[name, 2, True] + third[name, 3, True] < 0.9 * (third[name, 2, False] + third[name, 3, False]), third


#: the benchmark's `pairing + stall + sag`: neighbouring jets that pair, a part-load stall in
#: every fan's curve (each its own depth), a sagging supply and a tilted fan
PAIRING_STALL = [{'name': 'jet_pairing', 'pull': 0.05, 'thrust_ref': 3.0},
                 {'name': 'stall_dip', 'depth': 0.25, 'at': 0.35, 'width': 0.08, 'seed': 3},
                 {'name': 'supply_sag', 'sag': 0.2}, {'name': 'tilted_fan', 'fan': 'HM3', 'shift': [-0.03, 0.02]}]


def test_the_second_step_does_not_cross_the_stall_dip_it_has_fitted():
    """The soaring profile on that tunnel, seeds 0 and 3: after the first step the corrected
    prior sees a better field past its fitted stall dips (the edge fans from 0.5 to 0.1-0.2,
    the central one up to 0.55), through fields it predicts far worse. Taken, that step more
    than doubled the distance to the best error (1.61 / 1.76 x it, measured); kept on the base's
    side of the ridge it stays near the base (1.12 / 1.10 x). The guard is tested with each
    fan's own curve alone: the shipped fit also bends the curve every fan shares here, which
    places the dips where they are, so it sees no ridge, and its step must land as well. The
    step is longer than the reach: solved again with the commissioning's maps near its end
    (``commissioning_landing``, held off for the guard's test) it lands near the base too."""
    setup, effects, cal, maps = _commissioned(PAIRING_STALL)
    shaping, kp = setup.shaping, setup.geometry.key_points
    assert shaping.make_rule().ridge_share > 0 and shaping.make_rule().shared_curve_sd > 0
    target = setup.make_target('parabolic').values(kp)
    after, ridges = {}, {}
    own_curves = {'shared_curve_sd': 0.0, 'commissioning_landing': False}
    for seed in (0, 3):
        for case, overrides in (('guard', own_curves), ('no guard', {**own_curves, 'ridge_share': 0.0}),
                                ('shipped', {})):
            records, error = _run((setup, effects, cal, maps), target, seed, overrides, 2)
            ridges[seed, case] = records[-1].info['ridge']
            after[seed, case] = error
        assert ridges[seed, 'guard'] is not None and ridges[seed, 'no guard'] is None, ridges
        assert after[seed, 'guard'] < 0.8 * after[seed, 'no guard'], after
        assert after[seed, 'shipped'] < 0.8 * after[seed, 'no guard'], after


#: the drawn bench tunnel `random 2030-1`: LM3's ESC leaks into the central fan's command, the
#: ceiling sends a share of the jets back down, HM2's jet lands stretched; the uniform profile's
#: best commands keep the edge fans at 0.13-0.17 PWM
CROSSTALK_DOWNWASH = [{'name': 'esc_crosstalk', 'fan': 'CM', 'source': 'LM3', 'coupling': 0.272},
                      {'name': 'ceiling_downwash', 'share': 0.162},
                      {'name': 'elongated_footprint', 'fan': 'HM2', 'ratio': 1.475, 'angle': 0.611}]


def test_a_step_switches_a_running_fan_off_only_for_a_gain_a_sweep_can_tell():
    """Two steps in, the corrected prior promises a little more by turning edge fans off from
    about 0.1 PWM, where no map of the run had them; the crosstalk it does not hold makes that
    sweep worse. Taken half way down instead (``off_margin``, 1 by default), unless
    switching them off gains more than one sweep's noise, the fourth sweep stays nearer the best.
    Both runs start from the first sweep (``first_step_from_level`` 0): from the level map the
    first step runs every edge fan and the second has none to switch off from 0.1 PWM."""
    setup, effects, cal, maps = _commissioned(CROSSTALK_DOWNWASH)
    shaping, kp = setup.shaping, setup.geometry.key_points
    assert shaping.make_rule().off_margin == 1.0
    target = setup.make_target('uniform').values(kp)
    third, held = {}, {}
    for seed in (1, 3):
        for margin in (1.0, 0.0):
            records, error = _run((setup, effects, cal, maps), target, seed,
                                  {'first_step_from_level': 0, **({} if margin else {'off_margin': 0.0})}, 3)
            held[seed, margin] = sum(r.info.get('held_on', 0) for r in records)
            third[seed, margin] = error
    on, bounds = setup.geometry.fans.enabled, shaping.bounds
    start = np.where(np.arange(len(on)) == len(on) - 1, 0.45, 0.15)
    for seed in (1, 3):
        best = _best_error(setup.make_sim(seed=seed, effects=effects), kp, target, on, bounds, [start])
        assert held[seed, 1.0] > 0 and held[seed, 0.0] == 0, held
        # measured: 1.11 / 1.07 x the best against 1.30 / 1.17 x
        assert third[seed, 1.0] - best < 0.6 * (third[seed, 0.0] - best), (third, best)


def test_a_far_step_can_weigh_the_commissioning_maps_near_where_it_lands_as_well():
    """``commissioning_landing``: a map far from the base but at the step's end weighs as much as
    one at the base; one far from both fades as before."""
    from dataclasses import replace as _replace

    from wind_shaper.control import AdaptiveUpdate
    from wind_shaper.control.update import PastIteration, UpdateInput
    rule = AdaptiveUpdate(commissioning_weight=1.0, commissioning_reach=0.15, commissioning_landing=True)
    base = np.full(7, 0.3)
    maps = tuple(PastIteration(base + d, np.zeros(3)) for d in (0.0, 0.15, 0.3, -0.45))
    past = (PastIteration(base, np.zeros(3), info={'warm_start': {'check': {'mismatch': False}}}),)
    later = UpdateInput(1, base, np.zeros(3), None, np.ones(7, bool), target=np.zeros(3), prior_maps=maps,
                        history=past)
    w = rule._commissioning_weights(later, past, 0, None, base, landing=base + 0.3)
    assert w == pytest.approx([1.0, np.exp(-1.0), 1.0, np.exp(-9.0)])
    assert rule._commissioning_weights(_replace(later, history=past), past, 0, None, base) == \
        pytest.approx([1.0, np.exp(-1.0), np.exp(-4.0), np.exp(-9.0)])


#: the drawn bench tunnel `random 2035-1`: every fan's curve dips 26 % at 0.49 PWM, neighbouring
#: jets pull together, the straightener's vanes ripple the field
STALL_PAIRING_RIPPLE = [{'name': 'stall_dip', 'depth': 0.26, 'at': 0.491, 'width': 0.104, 'seed': 788},
                        {'name': 'jet_pairing', 'pull': 0.056},
                        {'name': 'vane_ripple', 'depth': 0.121, 'wavelength': 0.492, 'direction': 172.1,
                         'phase': 0.66}]


def test_a_far_second_step_fitted_on_the_maps_near_its_end_lands_nearer_the_optimum():
    """The soaring profile on that tunnel: the second step moves fans by more than the reach,
    into commands where the fit had only faded commissioning maps. Solved again with the maps
    near its end weighed in (``commissioning_landing``), it lands nearer the best field, seeds
    0 and 1 (measured: 1.27 / 1.26 N^2 without, 1.17 / 1.16 with; in the benchmark, 4 seeds,
    1.23-1.33 x the best error at k = 2 without, 1.18-1.21 with)."""
    setup, effects, cal, maps = _commissioned(STALL_PAIRING_RIPPLE)
    shaping, kp = setup.shaping, setup.geometry.key_points
    assert shaping.make_rule().commissioning_landing              # the shipped default
    target = setup.make_target('parabolic').values(kp)
    after, landed = {}, {}
    for seed in (0, 1):
        for on in (False, True):
            records, error = _run((setup, effects, cal, maps), target, seed, {'commissioning_landing': on}, 2)
            landed[seed, on] = 'landing' in records[-1].info
            after[seed, on] = error
        assert landed[seed, True] and not landed[seed, False], landed
    assert all(after[s, True] < 0.95 * after[s, False] for s in (0, 1)), after


#: a drag law, swirl and neighbours starving each other (the benchmark's `random 2026-9`): the
#: prior's optimum for the Gaussian profile leaves four ring fans at or near idle
STARVING_NEIGHBOURS = [{'name': 'drag_law', 'exponent': 0.255}, {'name': 'swirl', 'gain': -0.408},
                       {'name': 'neighbour_starvation', 'coupling': 0.387}]


def test_a_first_step_from_the_level_map_where_the_warm_start_leaves_fans_low():
    """The Gaussian profile on that tunnel, its prior commissioned from `lhs:6+level`: from the
    first sweep (four ring fans at 0-0.06 PWM) the first step extrapolates the fans' curves from
    where no map shows them; from the level map the commissioning measured best it interpolates.
    After the second update the field is nearer the target on both seeds (measured [N^2], seeds
    2, 3: 0.0394 / 0.0392 from the level map, 0.0426 / 0.0408 from the first sweep)."""
    setup, effects, cal, maps = commissioned = _commissioned(STARVING_NEIGHBOURS)
    assert setup.shaping.make_rule().first_step_from_level == 2
    target = setup.make_target('gaussian@LM1').values(setup.geometry.key_points)
    after = {}
    for seed in (2, 3):
        for fans in (0, 2):
            records, after[seed, fans] = _run(commissioned, target, seed, {'first_step_from_level': fans}, 2)
            assert records[0].info['from_level'] == bool(fans) and not records[1].info['from_level']
            assert int(np.sum(records[0].pwm < 0.15)) >= 4
    assert all(after[s, 2] < after[s, 0] for s in (2, 3)), after
    assert after[2, 2] + after[3, 2] < 0.97 * (after[2, 0] + after[3, 0]), after


def test_the_first_step_stays_on_the_first_sweep_where_the_warm_start_runs_every_fan():
    """The soaring profile on the same tunnel keeps every ring fan running at the warm start, and
    a prior commissioned fan by fan has no level map: the first step goes from the first sweep."""
    setup, effects, cal, maps = commissioned = _commissioned(STARVING_NEIGHBOURS)
    target = setup.make_target('parabolic').values(setup.geometry.key_points)
    records, _ = _run(commissioned, target, 2, {}, 1)
    assert int(np.sum(records[0].pwm[setup.geometry.fans.enabled] < 0.15)) < 2
    assert not records[0].info['from_level']
    records, _ = _run((setup, effects, cal, ()), setup.make_target('gaussian@LM1').values(setup.geometry.key_points),
                      2, {}, 1)
    assert not records[0].info['from_level']


@pytest.mark.parametrize('name', ['first_step_from_level', 'first_step_from_top'])
@pytest.mark.parametrize('fans', [-1, 1.5, True, '2'])
def test_a_first_step_from_level_setting_that_is_not_a_count_of_fans_is_refused(name, fans):
    from wind_shaper.control.adaptive import AdaptiveUpdate
    from wind_shaper.core.errors import ConfigError
    with pytest.raises(ConfigError, match=name):
        AdaptiveUpdate(**{name: fans})


def test_the_first_step_from_the_level_map_is_the_first_updates_only():
    """A caller that keeps no history (k > 0, no past iterations) never steps from the level
    map; the first update (k = 0) does, from the level map that measured best."""
    from wind_shaper.control.update import PastIteration, UpdateInput
    setup = Setup.load()
    sim = setup.make_sim(seed=0)
    kp, on, model = setup.geometry.key_points, setup.geometry.fans.enabled, setup.load_model()
    target = setup.make_target('gaussian@LM1').values(kp)
    std = np.full(len(kp), 0.03)

    def measure(U):
        return PastIteration(np.asarray(U, float), sim.true_field(U, kp), std)
    levels = (measure(np.full(7, 0.325)), measure(np.full(7, 0.195)))
    start = np.r_[np.full(6, 0.05), 0.45]                  # every ring fan low
    now = measure(start)
    rule = setup.shaping.make_rule()
    for k, fired in ((0, True), (2, False)):
        inp = UpdateInput(k, now.U, target - now.mean, None, on, std=std, model=model, key_points=kp,
                          target=target, prior_maps=levels)
        step = rule.step(inp)
        assert step.info['from_level'] == fired
    best = int(np.argmin([np.mean((m.mean - target) ** 2) for m in levels]))
    first = rule.step(UpdateInput(0, now.U, target - now.mean, None, on, std=std, model=model,
                                  key_points=kp, target=target, prior_maps=levels))
    assert first.info['base_k'] == best


#: ring jets pushed outward by their own speed, a central jet that flaps when its fan outruns the
#: ring, a weak fan (the benchmark's `outflow + flapping + weak`; effects of a bench plugin)
OUTFLOW_FLAPPING_WEAK = [{'name': 'own_thrust_outflow', 'drift': 0.04}, {'name': 'centre_jet_flapping', 'flap': 0.5},
                         {'name': 'weak_fan', 'fan': 'HM1', 'gain': 0.8}]


@pytest.fixture
def flapping_effects(monkeypatch):
    """The bench plugin's effects registered for this test alone: imported under a private name
    with its registration held back, then added to the registry so that the test's end takes
    them out again (a plugin left registered would change what the simulator's own tests see)."""
    import importlib.util

    import wind_shaper.sim as sim_pkg
    from wind_shaper.sim.effects import HIDDEN_EFFECTS
    path = Path(__file__).resolve().parents[3] / 'bench' / 'tunnels' / 'written_2026-12-04b' / 'lab_effects_i.py'
    monkeypatch.setattr(sim_pkg, 'register_effects', lambda *classes: None)
    spec = importlib.util.spec_from_file_location('_flapping_effects_for_a_test', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    for cls in (module.OwnThrustOutflow, module.CentreJetFlapping, module.GantryStrutWake):
        monkeypatch.setitem(HIDDEN_EFFECTS, cls.name, cls)


def test_a_first_step_from_the_level_map_where_the_warm_start_holds_a_fan_at_the_top(flapping_effects):
    """The uniform profile on that tunnel, its prior commissioned from `lhs:6+level`: the prior
    underrates the central fan and the warm start runs it at u_max, where more of it lowers the
    force at the centre. From the first sweep the steps learn that slowly; from the level map
    the first step brings the central fan down with the others running. After the second
    update the field is nearer the target on both seeds (measured [N^2], seeds 0, 1: 0.133 /
    0.130 from the level map, 0.242 / 0.241 from the first sweep)."""
    setup, effects, cal, maps = commissioned = _commissioned(OUTFLOW_FLAPPING_WEAK)
    rule = setup.shaping.make_rule()
    assert rule.first_step_from_top == 1 and rule.first_step_from_level == 2
    target = setup.make_target('uniform').values(setup.geometry.key_points)
    u_max, centre = setup.shaping.u_max, setup.geometry.fans.index('CM')
    after = {}
    for seed in (0, 1):
        for fans in (0, 1):
            records, after[seed, fans] = _run(commissioned, target, seed, {'first_step_from_top': fans}, 2)
            assert records[0].pwm[centre] == pytest.approx(u_max)
            assert records[0].info['from_level'] == bool(fans) and not records[1].info['from_level']
    assert all(after[s, 1] < 0.8 * after[s, 0] for s in (0, 1)), after
