"""A node that runs but answers no call is restarted (`wind-shaper up --deaf-after`).

Real rclpy node processes under the supervisor, probed from another process through their
parameter service as `up` does. A node frozen with SIGSTOP stands in for the deaf one (its
heartbeat is switched off here, so only the answers can tell). --deaf-after is 12 s here: on a
loaded machine a node's first answers were lost while its reply path was still being matched
(rclpy: "failed to send response"), and a 6 s limit once killed the healthy node at its start."""
import io
import os
import signal
import sys
import textwrap
import time

import pytest

from wind_shaper.supervisor import NodeSpec, RestartPolicy, Supervisor

pytest.importorskip('rclpy')

NODE = '''
import sys
from rclpy.node import Node
from wind_shaper.ros import runner

class Idle(Node):
    def __init__(self):
        super().__init__(sys.argv[1])

raise SystemExit(runner.run(Idle))
'''


def test_a_node_that_answers_no_call_is_killed_and_restarted_and_one_that_answers_is_not(
        ros_env, tmp_path):
    from wind_shaper.cli.graph import _GraphClient
    script = tmp_path / 'idle_node.py'
    script.write_text(textwrap.dedent(NODE))
    specs = [NodeSpec(name, (sys.executable, '-u', str(script), name)) for name in ('answers', 'frozen')]
    sup = Supervisor(specs, env=ros_env, out=io.StringIO(), grace_s=2.0,
                     policy=RestartPolicy(backoff_s=0.1, max_backoff_s=0.2, hang_after_s=0.0,
                                          deaf_after_s=12.0))
    client = _GraphClient(ros_env)
    try:
        sup.start()
        sup.watch_answers(client.answers)
        first = sup.pids()
        answered = {}

        def both_answered():
            answered.update(client.answers(list(sup.pids())))
            return {'answers', 'frozen'} <= set(answered)
        t0 = time.monotonic()
        sup.supervise(lambda: both_answered() or time.monotonic() - t0 > 30, interval_s=0.05)
        assert {'answers', 'frozen'} <= set(answered), sup.out.getvalue()
        assert sup.pids() == first, sup.out.getvalue()
        os.kill(first['frozen'], signal.SIGSTOP)
        t1 = time.monotonic()
        sup.supervise(lambda: len(sup.all_pids()) >= 3 or time.monotonic() - t1 > 30, interval_s=0.05)
        out = sup.out.getvalue()
        took = time.monotonic() - t1
        assert len(sup.all_pids()) == 3, out
        assert 'node frozen (pid' in out and 'deaf to the graph' in out, out
        assert 'restarting frozen (1 of 3)' in out, out
        assert took >= 12.0 - 0.5, f'killed after {took:.1f} s, before --deaf-after'
        assert sup.pids()['answers'] == first['answers'] and 'node answers' not in out, out
        # the restarted node answers again, and is left alone
        restarted = sup.pids()['frozen']
        t2 = time.monotonic()
        sup.supervise(lambda: client.answers(['frozen']).get('frozen', 0) > t2
                      or time.monotonic() - t2 > 20, interval_s=0.05)
        assert client.answers(['frozen']).get('frozen', 0) > t2, sup.out.getvalue()
        assert sup.pids()['frozen'] == restarted and sup.out.getvalue().count('deaf to the graph') == 1
    finally:
        for pid in sup.pids().values():
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
        client.close()
        sup.shutdown(2.0)
