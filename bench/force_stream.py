"""Force stream end to end: SimNetFtServer -> force_sensor process -> subscriber process.

For each rate the simulated Net F/T (in this process) streams records whose Fx and Fz carry the
record index k (counts_per_force 1, so Fx = Fz = k exactly); the force_sensor node runs in its
own process; a subscriber in a third process counts the samples of ``--stream`` (``block``:
/wind_shaper/force/block, the ForceBlocks the field estimator reads; ``wrench``:
/wind_shaper/force, one WrenchStamped per sample) for ``--seconds`` from its first message. In that window: sent = last k - first k + 1, received = distinct k seen, lost =
sent - received (every gap, whether at the UDP hop or the ROS hop); the UDP-hop share comes from
the node's own sequence counters in /diagnostics (since its start). Also printed: the CPU
(percent of one core) of the subscriber and of the node process, and the server's late skips
(the sender thread could not keep the rate). Figures only: no timed asserts. 1 kHz must be
lossless: PASS/FAIL, exit code 1 on FAIL.

Usage: python bench/force_stream.py [--rates 1000 2000 4000 7000] [--seconds 3]
       [--stream block|wrench] [--subscriber-executor single|events]
       [--node-executor single|events] [--depth N] [--json out.json]
(``--subscriber`` and ``--node`` are the child processes' modes.)
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time

REQUIRED_LOSSLESS_HZ = 1000


# ------------------------------------------------------------------------------ child: node
def _set_depth(depth: int | None) -> None:
    """Bench-only experiment: another history depth for the STREAM QoS of this process."""
    if depth:
        from wind_shaper.ros import qos
        qos.STREAM.depth = depth


def node_main(executor: str, ros_args: list[str], depth: int | None) -> int:
    _set_depth(depth)
    from wind_shaper.nodes.force_sensor import ForceSensorNode
    from wind_shaper.ros.runner import run
    return run(ForceSensorNode, ['force_sensor', *ros_args], executor=executor)


# ------------------------------------------------------------------------------ child: subscriber
def subscriber_main(executor: str, seconds: float, wait_s: float, depth: int | None,
                    stream: str) -> int:
    _set_depth(depth)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import WrenchStamped
    from rclpy.task import Future

    from wind_shaper.ros import names, qos

    rclpy.init()
    node = rclpy.create_node('force_stream_bench_subscriber')
    ks: list[float] = []
    window = {}
    done = Future()

    latency: list[float] = []

    def on_samples(k_values, stamps):
        if not ks:
            window['t0'] = time.monotonic()
            window['cpu0'] = time.process_time()
            print('START', flush=True)
        ks.extend(k_values)
        # the node stamps each sample with its arrival on the node's clock (the same machine's
        # clock here, also across network namespaces): stamp to receipt is the ROS hop (for a
        # block, its newest sample's)
        latency.append(time.time() - stamps[-1])
        if time.monotonic() - window['t0'] >= seconds and not done.done():
            window['t1'] = time.monotonic()
            window['cpu1'] = time.process_time()
            done.set_result(True)

    if stream == 'block':
        from wind_shaper_msgs.msg import ForceBlock
        node.create_subscription(ForceBlock, names.FORCE_BLOCK,
                                 lambda m: on_samples(m.force_z, m.stamp), qos.STREAM)
    else:
        node.create_subscription(WrenchStamped, names.FORCE, lambda m: on_samples(
            [m.wrench.force.x], [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec]),
            qos.STREAM)
    node_counts = {}

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name.startswith(names.FORCE_SENSOR):
                values = {kv.key: kv.value for kv in status.values}
                node_counts.update({k: int(values[k]) for k in ('received', 'lost', 'published')})

    node.create_subscription(DiagnosticArray, names.DIAGNOSTICS, on_diagnostics, 10)
    if executor == 'events':
        from rclpy.experimental import EventsExecutor
        ex = EventsExecutor()
    else:
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor()
    ex.add_node(node)
    deadline = time.monotonic() + wait_s + seconds
    while not done.done() and time.monotonic() < deadline and rclpy.ok():
        ex.spin_until_future_complete(done, timeout_sec=0.2)
    if done.done():
        counted = [int(round(k)) for k in ks]
        lat = sorted(latency)
        result = dict(first=min(counted), last=max(counted), messages=len(counted),
                      distinct=len(set(counted)), window_s=window['t1'] - window['t0'],
                      cpu_s=window['cpu1'] - window['cpu0'], node_counts=node_counts,
                      latency_median_ms=1e3 * lat[len(lat) // 2],
                      latency_p99_ms=1e3 * lat[min(len(lat) - 1, int(0.99 * len(lat)))])
    else:
        result = dict(error=f'{len(ks)} messages within {wait_s + seconds:.0f} s')
    print('RESULT ' + json.dumps(result), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------------------ orchestrator
def _cpu_seconds(pid: int) -> float:
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _stop(process: subprocess.Popen, grace_s: float = 5.0) -> None:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=grace_s)


def run_rate(rate: float, seconds: float, sub_executor: str, node_executor: str,
             env: dict, depth: int | None = None, stream: str = 'block') -> dict:
    from wind_shaper.sim import SimNetFtServer

    def source(t):
        k = round(t * rate)
        return (k, 0.0, k, 0.0, 0.0, 0.0)   # Fx = Fz = record index k [counts]

    me = os.path.abspath(__file__)
    wait_s = 20.0
    with SimNetFtServer(source, rate_hz=rate, counts_per_force=1.0, counts_per_torque=1.0,
                        max_batch=1000) as server:
        extra = ['--depth', str(depth)] if depth else []
        sub = subprocess.Popen([sys.executable, me, '--subscriber', '--executor', sub_executor,
                                '--seconds', str(seconds), '--wait', str(wait_s), '--stream',
                                stream, *extra], env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               stdin=subprocess.DEVNULL, start_new_session=True)
        node = subprocess.Popen([sys.executable, me, '--node', '--executor', node_executor,
                                 *extra, '--ros-args', '-p', 'sensor_host:=127.0.0.1',
                                 '-p', f'sensor_port:={server.port}',
                                 '-p', 'counts_per_force:=1.0', '-p', 'counts_per_torque:=1.0',
                                 '--log-level', 'warn'],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            result, node_cpu0, t0 = None, None, None
            for line in sub.stdout:   # bounded: the subscriber gives up after wait_s + seconds
                if line.startswith('START'):
                    node_cpu0, t0 = _cpu_seconds(node.pid), time.monotonic()
                    skips0 = server.fault_log().late_skips
                elif line.startswith('RESULT '):
                    result = json.loads(line[7:])
                    if node_cpu0 is not None:
                        result['node_cpu_pct'] = 100.0 * (_cpu_seconds(node.pid) - node_cpu0) / (
                            time.monotonic() - t0)
                        result['late_skips'] = server.fault_log().late_skips - skips0
                    break
            sub.wait(timeout=10)
        finally:
            _stop(sub)
            _stop(node)
    result = result or {'error': 'the subscriber printed no result'}
    result['rate_hz'] = rate
    if 'error' not in result:
        sent = result['last'] - result['first'] + 1
        result.update(sent=sent, received=result['distinct'], lost=sent - result['distinct'],
                      loss_pct=100.0 * (sent - result['distinct']) / sent,
                      sub_cpu_pct=100.0 * result['cpu_s'] / result['window_s'])
        c = result.get('node_counts') or {}
        # the node's own sequence counters (since it started, up to its last report): the part
        # of the loss that happened before ROS, between the sensor and the node
        total = c.get('received', 0) + c.get('lost', 0)
        result['udp_loss_pct'] = 100.0 * c.get('lost', 0) / total if total else float('nan')
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rates', type=float, nargs='+', default=[1000, 2000, 4000, 7000])
    ap.add_argument('--seconds', type=float, default=3.0, help='counting window per rate [s]')
    ap.add_argument('--stream', choices=['block', 'wrench'], default='block',
                    help='what the subscriber counts: the ForceBlocks the field estimator reads '
                    '(default) or the per-sample WrenchStamped')
    ap.add_argument('--subscriber-executor', choices=['single', 'events'], default='single')
    ap.add_argument('--node-executor', choices=['single', 'events'], default='single')
    ap.add_argument('--depth', type=int, default=None,
                    help='experiment: history depth of the force QoS (default: ros.qos.STREAM)')
    ap.add_argument('--json', default=None)
    ap.add_argument('--subscriber', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--node', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--executor', default='events', help=argparse.SUPPRESS)
    ap.add_argument('--wait', type=float, default=20.0, help=argparse.SUPPRESS)
    args, rest = ap.parse_known_args(argv)
    if args.node:
        return node_main(args.executor, rest, args.depth)
    if args.subscriber:
        return subscriber_main(args.executor, args.seconds, args.wait, args.depth, args.stream)

    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.pop('ROS_LOCALHOST_ONLY', None)
    env.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 101 + 1))
    from wind_shaper.ros import qos
    depth = args.depth or qos.STREAM.depth
    print(f'force stream: SimNetFtServer -> force_sensor ({args.node_executor} executor) -> '
          f'{args.stream} subscriber ({args.subscriber_executor} executor), QoS depth {depth}, '
          f'{args.seconds:g} s per rate, ROS_DOMAIN_ID {env["ROS_DOMAIN_ID"]}, '
          f'{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}')
    header = (f'{"rate Hz":>8} {"sent":>7} {"received":>8} {"lost":>6} {"loss %":>7} '
              f'{"sub CPU %":>9} {"node CPU %":>10} {"late skips":>10} {"UDP-hop loss %":>14}')
    print(header)
    rows = []
    for rate in args.rates:
        r = run_rate(rate, args.seconds, args.subscriber_executor, args.node_executor, env,
                     args.depth, args.stream)
        rows.append(r)
        if 'error' in r:
            print(f'{rate:>8.0f} error: {r["error"]}', flush=True)
        else:
            print(f'{rate:>8.0f} {r["sent"]:>7} {r["received"]:>8} {r["lost"]:>6} '
                  f'{r["loss_pct"]:>7.2f} {r["sub_cpu_pct"]:>9.0f} '
                  f'{r.get("node_cpu_pct", float("nan")):>10.0f} '
                  f'{r.get("late_skips", 0):>10} {r["udp_loss_pct"]:>14.2f}', flush=True)
    lossless = [r['rate_hz'] for r in rows if 'error' not in r and r['lost'] == 0]
    print(f'highest lossless rate: {max(lossless):.0f} Hz' if lossless else
          'no rate was lossless', f'(load average now {os.getloadavg()[0]:.1f})')
    required = [r for r in rows if r['rate_hz'] == REQUIRED_LOSSLESS_HZ]
    ok = bool(required) and all('error' not in r and r['lost'] == 0 for r in required)
    print(f'{"PASS" if ok else "FAIL"}: {REQUIRED_LOSSLESS_HZ} Hz '
          f'{"lossless" if ok else "lost samples or did not run"}')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(dict(stream=args.stream, subscriber_executor=args.subscriber_executor,
                           node_executor=args.node_executor, seconds=args.seconds, depth=depth,
                           rows=rows), f, indent=2)
    return 0 if ok else 1


if __name__ == '__main__':
    raise SystemExit(main())
