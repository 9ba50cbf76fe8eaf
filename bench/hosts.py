"""The graph across hosts: force stream rate and latency, and the latency to the live point cloud.

Three hosts are Linux network namespaces joined by veth pairs through a bridge
(``tools/netns_hosts.py``; root and iproute2 needed); DDS runs over UDP only, discovery on the
subnet. Two measurements, figures only (no pass/fail beyond "1 kHz lossless"):

1. **Force stream.** For each rate a simulated Net F/T and the force_sensor node run on the
   tunnel host, a subscriber on the shaping host (``bench/force_stream.py``'s child modes). In a
   window of ``--seconds``: lost samples (every gap: UDP hop and ROS hop) and the latency from
   the node's stamp (the sample's arrival from the sensor) to the subscriber's receipt, median
   and 99th percentile. The same rate with the subscriber on the tunnel host itself is run
   alongside: the ratio is what the network adds.
2. **Live point cloud.** The graph split as a lab runs it (``wind-shaper up --nodes ...`` on
   each host, ``--live`` with the coordinator) shapes the simulated tunnel for ``--iterations``;
   a subscriber on the mocap host takes each ``wind_shaper/live/field`` point cloud. Its stamp
   is the last force/pose sample of the sweep, so receipt - stamp is the time from the sweep's
   last sample on the wire to the point cloud on another host (alignment, GET_CLOSEST, the GP,
   the live view and two network hops).

Usage: sudo python bench/hosts.py [--rates 1000 2000 4000] [--seconds 3] [--iterations 3]
       [--json bench/out/hosts.json]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tools'))
sys.path.insert(0, str(ROOT / 'bench'))
from force_stream import _stop  # noqa: E402  (SIGINT, then SIGKILL after a grace time)
PYTHON = sys.executable
FORCE_STREAM = str(ROOT / 'bench' / 'force_stream.py')


def _env(domain: int) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET',
               FASTDDS_BUILTIN_TRANSPORTS='UDPv4', PYTHONUNBUFFERED='1')
    for key in ('ROS_LOCALHOST_ONLY', 'ROS_STATIC_PEERS', 'WIND_SHAPER_NAMESPACE'):
        env.pop(key, None)
    return env


# ------------------------------------------------------------------------- child: Net F/T server
def server_main(rate: float) -> int:
    """The simulated Net F/T in a process of its own (Fx = Fz = record index: the subscriber
    counts Fz of the force blocks); prints its port."""
    from wind_shaper.sim import SimNetFtServer
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    with SimNetFtServer(lambda t: (round(t * rate), 0.0, round(t * rate), 0.0, 0.0, 0.0), rate_hz=rate,
                        counts_per_force=1.0, counts_per_torque=1.0, max_batch=1000) as server:
        print(f'PORT {server.port}', flush=True)
        while not stop:
            time.sleep(0.1)
    return 0


# ------------------------------------------------------------------------- part 1: force stream
def stream(hosts, rate: float, seconds: float, subscriber_host: int, domain: int) -> dict:
    env = _env(domain)
    server = subprocess.Popen([*hosts.exec(1), PYTHON, __file__, '--server', '--rate', str(rate)],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                              stdin=subprocess.DEVNULL, start_new_session=True)
    procs = [server]
    try:
        port = int(server.stdout.readline().split()[1])
        sub = subprocess.Popen([*hosts.exec(subscriber_host), PYTHON, FORCE_STREAM, '--subscriber',
                                '--executor', 'events', '--seconds', str(seconds), '--wait', '30'],
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               stdin=subprocess.DEVNULL, start_new_session=True)
        node = subprocess.Popen([*hosts.exec(1), PYTHON, FORCE_STREAM, '--node', '--executor', 'events',
                                 '--ros-args', '-p', 'sensor_host:=127.0.0.1', '-p', f'sensor_port:={port}',
                                 '-p', 'counts_per_force:=1.0', '-p', 'counts_per_torque:=1.0',
                                 '--log-level', 'warn'], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True)
        procs += [sub, node]
        result = None
        for line in sub.stdout:
            if line.startswith('RESULT '):
                result = json.loads(line[7:])
                break
        sub.wait(timeout=10)
    finally:
        for p in reversed(procs):
            _stop(p)
    result = result or {'error': 'the subscriber printed no result'}
    if 'error' not in result and result['messages'] > 1 and result['last'] == result['first']:
        # every sample carried the same index: the count below would read "lost 0 of 1"
        result = {'error': f"{result['messages']} samples all carried record index {result['first']}: "
                           'the sensor does not number its records in Fz'}
    if 'error' not in result:
        sent = result['last'] - result['first'] + 1
        result.update(sent=sent, lost=sent - result['distinct'],
                      loss_pct=100.0 * (sent - result['distinct']) / sent)
    result.update(rate_hz=rate, subscriber='other host' if subscriber_host != 1 else 'same host')
    return result


# ------------------------------------------------------------------------ part 2: point cloud
CLOUD_PROBE = '''
import sys, time, rclpy
from sensor_msgs.msg import PointCloud2
from wind_shaper.ros import qos
rclpy.init(); n = rclpy.create_node("cloud_probe")
seen = {}
def on_cloud(m):
    stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
    if stamp not in seen:
        seen[stamp] = time.time() - stamp
        print("CLOUD %d %.6f" % (m.width, seen[stamp]), flush=True)
n.create_subscription(PointCloud2, "wind_shaper/live/field", on_cloud, qos.COMMAND)
t0 = time.time()
while time.time() - t0 < float(sys.argv[1]):
    rclpy.spin_once(n, timeout_sec=0.1)
'''


def cloud(hosts, iterations: int, domain: int, workdir: Path) -> dict:
    env = _env(domain)
    up = [PYTHON, '-m', 'wind_shaper.cli.main', 'up', '--startup-timeout', '90']
    starts = [
        (1, ['--sim', '--nodes', 'fan_output,force_sensor']),
        (2, ['--nodes', 'mocap_relay']),
        (3, ['--nodes', 'field_estimator,coordinator', '--live', '--set', 'coordinator.settle_s=0.5',
             '--set', 'coordinator.sweep_duration_s=8']),
    ]
    procs, outputs = [], []
    try:
        for host, args in starts:
            log = open(workdir / f'up{host}.log', 'w')
            outputs.append(log)
            procs.append(subprocess.Popen([*hosts.exec(host), *up, *args], cwd=workdir, env=env,
                                          stdout=log, stderr=subprocess.STDOUT,
                                          stdin=subprocess.DEVNULL, start_new_session=True))
        deadline = time.monotonic() + 120
        while not all(re.search(r'all \d+ nodes are up', (workdir / f'up{h}.log').read_text())
                      for h, _ in starts):
            if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                raise RuntimeError('the graph did not come up: ' + ' | '.join(
                    (workdir / f'up{h}.log').read_text()[-800:] for h, _ in starts))
            time.sleep(0.5)
        probe = subprocess.Popen([*hosts.exec(2), PYTHON, '-c', CLOUD_PROBE, str(60 * iterations + 60)],
                                 env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                 stdin=subprocess.DEVNULL, start_new_session=True)
        procs.append(probe)
        time.sleep(3.0)
        it = subprocess.run([*hosts.exec(3), PYTHON, '-m', 'wind_shaper.cli.main', 'iterate',
                             '--count', str(iterations), '--wait', '40'], cwd=workdir, env=env,
                            capture_output=True, text=True, timeout=120 * iterations + 60)
        time.sleep(3.0)
        _stop(probe)
        lines = [ln.split() for ln in probe.stdout.read().splitlines() if ln.startswith('CLOUD')]
    finally:
        for p in reversed(procs):
            _stop(p, 10.0)
        for log in outputs:
            log.close()
    latencies = sorted(float(x[2]) for x in lines)
    return {'iterations_ok': it.returncode == 0, 'clouds': len(lines),
            'points': int(lines[0][1]) if lines else 0,
            'latency_s': latencies, 'iterate_tail': it.stdout[-600:] + it.stderr[-600:]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rates', type=float, nargs='+', default=[1000, 2000, 4000])
    ap.add_argument('--seconds', type=float, default=3.0)
    ap.add_argument('--iterations', type=int, default=3)
    ap.add_argument('--json', default='bench/out/hosts.json')
    ap.add_argument('--server', action='store_true', help=argparse.SUPPRESS)
    ap.add_argument('--rate', type=float, default=1000.0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.server:
        return server_main(args.rate)
    if os.geteuid() != 0:
        print('bench/hosts.py makes network namespaces: run it as root', file=sys.stderr)
        return 2
    from netns_hosts import Hosts
    hosts = Hosts(f'wb{os.getpid() % 100000}', f'10.78.{os.getpid() % 200 + 20}.')
    domain = 150 + os.getpid() % 50
    out = {'stream': [], 'cloud': None}
    t0 = time.perf_counter()
    try:
        hosts.create()
        for rate in args.rates:
            for where in (3, 1):   # the other host, then the same host in the same run
                r = stream(hosts, rate, args.seconds, where, domain)
                out['stream'].append(r)
                if 'error' in r:
                    print(f'{rate:6.0f} Hz, subscriber on the {r["subscriber"]}: {r["error"]}')
                else:
                    print(f'{rate:6.0f} Hz, subscriber on the {r["subscriber"]:10s}: lost {r["lost"]} of '
                          f'{r["sent"]} ({r["loss_pct"]:.2f} %), latency median {r["latency_median_ms"]:.2f} ms, '
                          f'p99 {r["latency_p99_ms"]:.2f} ms', flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            c = cloud(hosts, args.iterations, domain + 1, Path(tmp))
        out['cloud'] = c
        lat = c['latency_s']
        print(f'live point cloud on the mocap host: {c["clouds"]} clouds of {c["points"]} points over '
              f'{args.iterations} iterations (iterate ok: {c["iterations_ok"]}); sweep\'s last sample to '
              f'cloud: ' + (', '.join(f'{x:.3f}' for x in lat) + ' s' if lat else 'none'))
    finally:
        hosts.remove()
    print(f'({time.perf_counter() - t0:.0f} s)')
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1))
    print(f'wrote {args.json}')
    ok = all('error' not in r and r['lost'] == 0 for r in out['stream'] if r['rate_hz'] == 1000)
    return 0 if ok else 1


if __name__ == '__main__':
    raise SystemExit(main())
