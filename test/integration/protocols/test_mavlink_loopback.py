"""MavlinkFanLink against SimAutopilot over UDP loopback, real pymavlink on both ends."""
import os
import statistics
import time

import pytest

from wind_shaper.protocols.errors import FanCommandError
from wind_shaper.protocols.mavlink_fans import FanChannelMap, mavlink
from wind_shaper.io import LinkConfigError, MavlinkFanLink, TransportError
from wind_shaper.sim.autopilot import SimAutopilot

FLAVOURS = ['ardupilot_servo', 'ardupilot_rc_override', 'px4_actuator']
TOL = 1.0 / 1000 + 1e-9          # one microsecond over a 1000 us range


def channel_map(**kw):
    return FanChannelMap.from_config({'f1': 1, 'f2': 2, 'f3': 7, 'f4': 9}, u_max=0.8, **kw)


def close_to(applied, wanted):
    return applied.keys() >= wanted.keys() and all(
        abs(applied[k] - v) <= TOL for k, v in wanted.items())


@pytest.fixture
def pair(request):
    """(autopilot, link) for a flavour; both closed afterwards."""
    made = []

    def make(flavour, ap_kw=None, link_kw=None):
        ap = SimAutopilot(flavour=flavour, **(ap_kw or {}))
        made.append(ap)
        link = MavlinkFanLink(ap.url, flavour, channel_map(), **(link_kw or {}))
        made.append(link)
        return ap, link

    yield make
    for obj in reversed(made):
        obj.close()


@pytest.mark.parametrize('flavour', FLAVOURS)
def test_commands_reach_the_autopilot_and_come_back_as_applied_fractions(pair, wait_for,
                                                                         flavour):
    seen = []
    ap, link = pair(flavour, link_kw=dict(on_outputs=seen.append))
    assert link.wait_heartbeat(3.0), 'no heartbeat from the simulated autopilot'
    wanted = {'f1': 0.25, 'f2': 0.5, 'f3': 0.8, 'f4': 0.1}
    result = link.send({'f1': 0.25, 'f2': 0.5, 'f3': 1.7, 'f4': 0.1}, wait_ack_s=1.0)
    assert result.clipped == ('f3',)                       # 1.7 > u_max 0.8: clipped, reported
    if flavour == 'ardupilot_rc_override':
        assert result.acks == ()
    else:
        assert result.accepted, result
    assert wait_for(lambda: close_to(link.applied, wanted), 2.0), (link.applied, ap.outputs())
    assert any(close_to(s, wanted) for s in seen)          # on_outputs callback saw it too
    assert {ch: ap.outputs()[ch] for ch in (1, 2, 7, 9)} == {1: 1250, 2: 1500, 7: 1800, 9: 1100}
    assert all(ap.outputs()[ch] == 1000 for ch in (3, 4, 5, 6, 8))   # others untouched


@pytest.mark.parametrize('flavour', ['ardupilot_servo', 'px4_actuator'])
def test_command_round_trip_time(pair, flavour):
    ap, link = pair(flavour)
    assert link.wait_heartbeat(3.0)
    rtts = []
    for i in range(50):
        r = link.send({'f1': i / 100}, wait_ack_s=1.0)
        assert r.accepted
        rtts.append(r.round_trip_s)
    median = statistics.median(rtts)
    print(f'\n{flavour}: COMMAND_LONG -> COMMAND_ACK median {median * 1e3:.3f} ms, '
          f'max {max(rtts) * 1e3:.3f} ms')
    assert median < 0.05


def test_rc_override_is_refreshed_and_times_out_to_safe_when_the_link_is_cut(pair, wait_for):
    ap, link = pair('ardupilot_rc_override', ap_kw=dict(rc_override_timeout_s=0.8),
                    link_kw=dict(rc_refresh_hz=10.0))
    assert link.wait_heartbeat(3.0)
    link.send({'f1': 0.6})
    assert wait_for(lambda: ap.outputs()[1] == 1600, 2.0)
    time.sleep(1.2)                                         # past the timeout: refresh holds it
    assert ap.outputs()[1] == 1600 and ap.counts['override_timeouts'] == 0
    ap.cut_link()
    t0 = time.monotonic()
    assert wait_for(lambda: ap.outputs()[1] == 1000, 3.0)
    assert 0.8 - 0.15 < time.monotonic() - t0 < 0.8 + 0.5
    assert ap.counts['override_timeouts'] == 1


@pytest.mark.parametrize('flavour', ['ardupilot_servo', 'ardupilot_rc_override'])
def test_heartbeat_loss_is_detected_in_time_and_fans_go_safe(pair, wait_for, flavour):
    events = []
    ap, link = pair(flavour, ap_kw=dict(heartbeat_hz=10.0),
                    link_kw=dict(heartbeat_timeout_s=0.5,
                                 on_link_lost=lambda: events.append(('lost', time.monotonic())),
                                 on_link_up=lambda: events.append(('up', time.monotonic()))))
    assert link.wait_heartbeat(3.0)
    link.send({'f1': 0.7, 'f4': 0.3}, wait_ack_s=1.0)
    assert wait_for(lambda: ap.outputs()[1] == 1700, 2.0)
    ap.pause_heartbeat()
    t0 = time.monotonic()
    assert wait_for(lambda: ('lost' in [e[0] for e in events]), 2.0)
    lost_at = [t for e, t in events if e == 'lost'][0]
    # detection is due at (last heartbeat + timeout) <= (pause + timeout); allow for scheduling
    assert lost_at - t0 <= 0.5 + 0.35, f'link loss noticed after {lost_at - t0:.3f} s'
    assert not link.link_up and link.stats.link_losses == 1
    # go_safe happened: the (still reachable) autopilot applies the safe value
    assert wait_for(lambda: ap.outputs()[1] == 1000 and ap.outputs()[9] == 1000, 1.0)
    assert link.commanded.pulses == {1: 1000, 2: 1000, 7: 1000, 9: 1000}
    ap.resume_heartbeat()
    assert wait_for(lambda: link.link_up, 1.0)
    assert [e for e, _ in events] == ['up', 'lost', 'up']


def test_cut_link_is_a_link_loss(pair, wait_for):
    lost = []
    ap, link = pair('px4_actuator', ap_kw=dict(heartbeat_hz=10.0),
                    link_kw=dict(heartbeat_timeout_s=0.3, on_link_lost=lambda: lost.append(1)))
    assert link.wait_heartbeat(3.0)
    ap.cut_link()
    assert wait_for(lambda: lost, 1.0)
    r = link.send({'f1': 0.5}, wait_ack_s=0.2)             # nothing gets through: no ACK
    assert r.acks == () and not r.accepted and r.round_trip_s is None


def test_bad_channel_is_denied():
    ap = SimAutopilot(flavour='ardupilot', n_channels=8)
    try:
        fans = FanChannelMap.from_config({'ok': 1, 'missing': 12})
        with MavlinkFanLink(ap.url, 'ardupilot_servo', fans) as link:
            assert link.wait_heartbeat(3.0)
            r = link.send({'ok': 0.5, 'missing': 0.5}, wait_ack_s=1.0)
            assert sorted(r.acks) == [mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED]
            assert not r.accepted and link.stats.denied == 1
        with MavlinkFanLink(ap.url, 'px4_actuator', fans) as link:
            assert link.wait_heartbeat(3.0)
            r = link.send({'missing': 0.5}, wait_ack_s=1.0)
            assert r.acks == (mavlink.MAV_RESULT_DENIED,)
    finally:
        ap.close()


def test_nan_is_refused_and_nothing_is_sent(pair):
    ap, link = pair('ardupilot_servo')
    assert link.wait_heartbeat(3.0)
    with pytest.raises(FanCommandError, match='NaN'):
        link.send({'f1': float('nan')})
    time.sleep(0.05)
    assert ap.counts['set_servo'] == 0
    assert ap.outputs()[1] == 1000


def test_close_goes_safe_and_refuses_further_use(wait_for):
    ap = SimAutopilot(flavour='ardupilot')
    try:
        link = MavlinkFanLink(ap.url, 'ardupilot_servo', channel_map())
        assert link.wait_heartbeat(3.0)
        link.send({'f1': 0.5, 'f2': 0.6}, wait_ack_s=1.0)
        assert ap.outputs()[2] == 1600
        link.close()
        assert wait_for(lambda: ap.outputs()[1] == 1000 and ap.outputs()[2] == 1000, 1.0)
        with pytest.raises(TransportError, match='closed'):
            link.send({'f1': 0.5})
        link.close()                                        # idempotent
    finally:
        ap.close()


@pytest.mark.fault
def test_signed_link_works_and_a_wrong_key_or_no_signing_is_rejected(wait_for, fault_row):
    key = os.urandom(32)
    ap = SimAutopilot(flavour='ardupilot', signing_key=key)
    links = []
    try:
        good = MavlinkFanLink(ap.url, 'ardupilot_servo', channel_map(), signing=True,
                              signing_key=key)
        links.append(good)
        assert good.wait_heartbeat(3.0)
        assert good.send({'f1': 0.4}, wait_ack_s=1.0).accepted
        assert ap.outputs()[1] == 1400
        assert good.signing_stats['good'] > 0
        for kw in (dict(signing=True, signing_key=bytes(32)), dict()):
            bad = MavlinkFanLink(ap.url, 'ardupilot_servo', channel_map(), **kw)
            links.append(bad)
            before = ap.counts['bad_data']
            r = bad.send({'f1': 0.9}, wait_ack_s=0.3)
            assert r.acks == ()
            assert ap.outputs()[1] == 1400
            assert ap.counts['bad_data'] > before
    finally:
        for link in links:
            link.close()
        ap.close()
    fault_row('MAVLink 2 packets with a wrong signing key, or unsigned, on a signed link',
              'rejected by the autopilot and by fan_output', True)


def test_udpin_link_learns_the_autopilot_that_calls_it(wait_for):
    link = MavlinkFanLink('udpin:127.0.0.1:0', 'ardupilot_servo', channel_map())
    ap = None
    try:
        host, port = link.local_address
        ap = SimAutopilot(flavour='ardupilot', peer=(host, port))
        assert link.wait_heartbeat(3.0)
        assert link.send({'f2': 0.3}, wait_ack_s=1.0).accepted
        assert ap.outputs()[2] == 1300
    finally:
        link.close()
        if ap is not None:
            ap.close()


@pytest.mark.parametrize('kw, msg', [(dict(url='serial-ish'), 'not understood'),
                                     (dict(flavour='mavros'), 'flavour'),
                                     (dict(signing=True), '32-byte'),
                                     (dict(heartbeat_timeout_s=0), 'heartbeat_timeout_s')])
def test_link_config_errors(kw, msg):
    args = dict(url='udpout:127.0.0.1:9', flavour='ardupilot_servo', channel_map=channel_map())
    args.update(kw)
    with pytest.raises(Exception, match=msg) as info:
        MavlinkFanLink(args.pop('url'), args.pop('flavour'), args.pop('channel_map'), **args)
    assert isinstance(info.value, (LinkConfigError, ValueError))
