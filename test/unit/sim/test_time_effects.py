"""Faults in time in the simulated tunnel (sim.unmodelled_sensing): the sensor's zero drifting over
the recording, fans that reach a new command through a first-order lag; tunnels without them
sweep exactly as before."""
import numpy as np
import pytest

from wind_shaper.app import Setup
from wind_shaper.sim import EffectError, SensorZeroDrift, UnsettledFans, make_effect


@pytest.fixture(scope='module')
def setup():
    return Setup.load()


def _sweeps(sim, commands, n=500):
    out = []
    for u in commands:
        sim.apply(np.full(sim.geometry.fans.n_fans, u))
        out.append(sim.sweep(n))
    return out


def test_the_zero_drifts_with_recording_time_fans_on_or_off(setup):
    clean = _sweeps(setup.make_sim(seed=1), [0.0, 0.5, 0.0])
    drift = _sweeps(setup.make_sim(seed=1, effects=[SensorZeroDrift(rate=0.01)]), [0.0, 0.5, 0.0])
    # 500 samples at 50 Hz: each sweep is 10 s of the recording clock
    for k, (a, b) in enumerate(zip(clean, drift)):
        t = 10.0 * k + a.times
        assert np.allclose(b.forces - a.forces, 0.01 * t)
        assert np.allclose(a.positions, b.positions)


def test_a_random_walk_of_the_zero_is_one_path_per_seed(setup):
    a = _sweeps(setup.make_sim(seed=1, effects=[SensorZeroDrift(rate=0.0, walk=0.05, walk_seed=3)]), [0.0] * 2)
    b = _sweeps(setup.make_sim(seed=1, effects=[SensorZeroDrift(rate=0.0, walk=0.05, walk_seed=3)]), [0.0] * 2)
    clean = _sweeps(setup.make_sim(seed=1), [0.0] * 2)
    walk = np.concatenate([x.forces - c.forces for x, c in zip(a, clean)])
    assert np.allclose(walk, np.concatenate([x.forces - c.forces for x, c in zip(b, clean)]))
    assert 0.01 < np.std(walk) < 0.5 and walk[0] == pytest.approx(0.0, abs=1e-9)


def test_unsettled_fans_read_the_previous_commands_first(setup):
    clean = _sweeps(setup.make_sim(seed=2), [0.0, 0.6, 0.6])
    lag = _sweeps(setup.make_sim(seed=2, effects=[UnsettledFans(tau=1.5)]), [0.0, 0.6, 0.6])
    assert np.allclose(lag[0].forces, clean[0].forces)          # no change before it
    short = clean[1].forces - lag[1].forces                      # spinning up: too little force
    assert np.mean(short[:25]) > 0.5 * np.mean(clean[1].forces[:25])     # the first 0.5 s
    assert abs(np.mean(short[-100:])) < 0.01 * np.mean(clean[1].forces[-100:])  # settled
    # same commands as before: only what is left of the last change (exp(-10 / 1.5) = 0.1 %)
    assert np.allclose(lag[2].forces, clean[2].forces, atol=0.02)


def test_a_wait_before_the_sweep_lets_the_fans_settle(setup):
    clean = _sweeps(setup.make_sim(seed=2), [0.0, 0.6])
    waited = _sweeps(setup.make_sim(seed=2, effects=[UnsettledFans(tau=1.0, wait=15.0)]), [0.0, 0.6])
    assert np.allclose(waited[1].forces, clean[1].forces, atol=1e-3)


def test_time_faults_are_registered_by_name_and_bounded():
    assert isinstance(make_effect('sensor_zero_drift'), SensorZeroDrift)
    assert make_effect('unsettled_fans', tau=2.0).tau == 2.0
    with pytest.raises(EffectError, match='physical bounds'):
        UnsettledFans(tau=-1.0)


def test_a_bias_with_every_fan_off_zeroes_the_drift_so_far(setup):
    clean, drift = setup.make_sim(seed=1), setup.make_sim(seed=1, effects=[SensorZeroDrift(rate=0.01)])
    a, b = _sweeps(clean, [0.5, 0.5]), _sweeps(drift, [0.5, 0.5])
    for sim in (clean, drift):   # 20 s of recording so far; every fan off, then zero the sensor
        sim.apply(np.zeros(sim.geometry.fans.n_fans))
        sim.bias_sensor()
    assert drift._bias == pytest.approx(0.01 * 20.0) and clean._bias == pytest.approx(0.0)
    a, b = _sweeps(clean, [0.5]), _sweeps(drift, [0.5])
    assert np.allclose(b[0].forces - a[0].forces, 0.01 * a[0].times)   # from zero again


def test_a_bias_with_the_fans_running_zeroes_their_force_too(setup):
    sim = setup.make_sim(seed=1)
    sim.apply(np.full(sim.geometry.fans.n_fans, 0.5))
    centre = sim.true_field(sim.pwm, np.zeros((1, 2)))[0]
    assert sim.bias_sensor() == pytest.approx(centre) and centre > 1.0
    before = setup.make_sim(seed=1)
    before.apply(sim.pwm)
    assert np.allclose(sim.sweep(200).forces, before.sweep(200).forces - centre)


def _loop(setup, sim, bias_zero):
    from wind_shaper.control import ShapingLoop
    target = setup.make_target('uniform').values(setup.geometry.key_points)
    return ShapingLoop.from_settings(sim, setup.load_model(), target, setup.shaping, u0=0.4,
                                     truth=lambda U: sim.true_field(U, setup.geometry.key_points),
                                     bias_zero=bias_zero)


def test_a_shaping_loop_biased_before_every_sweep_does_not_carry_the_drift_into_its_maps(setup):
    drift = dict(effects=[SensorZeroDrift(rate=0.02)])
    offsets, settle = {}, {}
    for mode in ('never', 'every_sweep'):
        loop = _loop(setup, setup.make_sim(seed=4, **drift), mode)
        recs = [loop.iterate(update=False) for _ in range(3)]
        offsets[mode] = [float(np.mean(r.estimate.mean - r.true_field)) for r in recs]
        settle[mode] = [r.settle_s for r in recs]
    # unbiased, each sweep's map sits higher by the zero of its time; biased, only the drift
    # within one sweep is left (the sweep's mean time x the rate)
    assert offsets['never'][2] > 2.0 * offsets['every_sweep'][2] + 0.1
    assert max(offsets['every_sweep']) < 0.02 * 20.0
    # a bias costs the spin-down before it and the spin-up after it
    fan_settle = setup.shaping.fan_settle_s
    assert settle['never'] == [fan_settle, 0.0, 0.0] and settle['every_sweep'] == [2.0 * fan_settle] * 3


def test_a_loop_on_a_tunnel_that_cannot_bias_refuses_bias_zero(setup):
    from wind_shaper.core.errors import ConfigError

    class NoBias:
        def __init__(self, sim):
            self.geometry, self._sim = sim.geometry, sim

        def apply(self, pwm):
            return self._sim.apply(pwm)

        def sweep(self, n_samples=1000):
            return self._sim.sweep(n_samples)

    with pytest.raises(ConfigError, match='bias_sensor'):
        _loop(setup, NoBias(setup.make_sim(seed=0)), 'every_sweep')
    with pytest.raises(ConfigError, match='never, fans_off, every_sweep'):
        _loop(setup, setup.make_sim(seed=0), 'sometimes')


def test_a_loop_whose_fans_may_not_stop_refuses_to_bias_before_every_sweep(setup):
    """shaping.u_min above 0: the loop cannot turn the fans off to bias the sensor."""
    from dataclasses import replace

    from wind_shaper.control import ShapingLoop
    from wind_shaper.core.errors import ConfigError
    shaping = replace(setup.shaping, u_min=0.05)
    sim = setup.make_sim(seed=1)
    target = setup.make_target('uniform').values(setup.geometry.key_points)
    with pytest.raises(ConfigError, match='u_min = 0.05'):
        ShapingLoop.from_settings(sim, setup.load_model(), target, shaping, u0=0.4, bias_zero='every_sweep')
    ShapingLoop.from_settings(sim, setup.load_model(), target, shaping, u0=0.4, bias_zero='fans_off')
