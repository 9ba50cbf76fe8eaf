"""Where the sweeps of a recording are: status intervals, command intervals (pure logic)."""
from wind_shaper.bag.segments import (CommandEvent, StatusEvent, segments_from_commands,
                                      segments_from_status)

S = 1_000_000_000
NAMES = ('fan_00', 'fan_01')


def status(t, k, state, pwm=(0.2, 0.4)):
    return StatusEvent(t * S, k, state, NAMES if pwm else (), pwm)


def test_a_sweep_runs_from_the_first_sweeping_status_to_the_next_state():
    events = [status(0, -1, 'idle', ()), status(1, 0, 'commanding'), status(2, 0, 'sweeping'),
              status(3, 0, 'sweeping'), status(4, 0, 'sweeping'), status(5, 0, 'estimating'),
              status(6, 0, 'done'), status(7, 1, 'commanding', (0.3, 0.5)),
              status(8, 1, 'sweeping', (0.3, 0.5)), status(9, 1, 'estimating', (0.3, 0.5))]
    segs = segments_from_status(list(reversed(events)), end_ns=10 * S)  # order does not matter
    assert [(s.start_ns, s.end_ns, s.iteration) for s in segs] == [(2 * S, 5 * S, 0), (8 * S, 9 * S, 1)]
    assert segs[0].pwm == (0.2, 0.4) and segs[1].pwm == (0.3, 0.5) and segs[0].fan_names == NAMES
    assert all(s.complete and s.source == 'status' for s in segs)


def test_a_new_iteration_closes_the_open_sweep_and_the_end_of_the_bag_leaves_one_incomplete():
    events = [status(1, 0, 'sweeping'), status(2, 1, 'sweeping'), status(3, 1, 'sweeping')]
    segs = segments_from_status(events, end_ns=4 * S)
    assert [(s.start_ns, s.iteration, s.complete) for s in segs] == [(S, 0, True), (2 * S, 1, False)]
    assert segs[0].end_ns == 2 * S and segs[1].end_ns == 4 * S + 1  # the last message is inside


def test_a_status_without_commands_takes_the_last_fan_command_before_the_sweep():
    commands = [CommandEvent(0, NAMES, (0.1, 0.1)), CommandEvent(S, NAMES, (0.6, 0.7)),
                CommandEvent(5 * S, NAMES, (0.9, 0.9))]
    segs = segments_from_status([status(2, 3, 'sweeping', ()), status(4, 3, 'failed', ())], 6 * S, commands)
    assert segs[0].pwm == (0.6, 0.7) and segs[0].fan_names == NAMES and segs[0].iteration == 3


def test_no_sweeping_status_means_no_sweep():
    assert segments_from_status([status(1, 0, 'commanding'), status(2, 0, 'failed')], 3 * S) == []


def test_command_changes_delimit_segments_and_repeats_do_not_split():
    commands = [CommandEvent(1 * S, NAMES, (0.2, 0.4)), CommandEvent(2 * S, NAMES, (0.2, 0.4)),
                CommandEvent(3 * S, NAMES, (0.2, 0.4 + 1e-9)), CommandEvent(4 * S, NAMES, (0.5, 0.4)),
                CommandEvent(6 * S, ('a', 'b'), (0.5, 0.4))]
    segs = segments_from_commands(commands, 0, 8 * S)
    assert [(s.start_ns, s.end_ns, s.pwm) for s in segs] == [
        (1 * S, 4 * S, (0.2, 0.4)), (4 * S, 6 * S, (0.5, 0.4)), (6 * S, 8 * S + 1, (0.5, 0.4))]
    assert segs[2].fan_names == ('a', 'b') and all(s.iteration == -1 for s in segs)


def test_without_commands_the_whole_recording_is_one_segment():
    (seg,) = segments_from_commands([], 5, 50)
    assert (seg.start_ns, seg.end_ns, seg.pwm, seg.source) == (5, 51, (), 'whole')
