"""Node start: the CPU a node process takes to import and to run its first seconds, each node
started alone with its default parameters (no sensor, autopilot or graph to talk to), as the
supervisor starts it again after a crash. Printed per node, the median over ``--repeats`` starts:
the CPU of importing the node's module [s], of the whole first ``--seconds`` [s, import
included], and whether SciPy was loaded by then (the GP and the optimisers need it; a node that
only relays messages should not pay for it).

    .venv/bin/python bench/node_start.py                       # every node, 3 starts of 5 s each
    .venv/bin/python bench/node_start.py --nodes mocap_relay --repeats 1 --seconds 2

Figures only, no timed asserts. Each child runs in its own ROS domain (the environment's
``ROS_DOMAIN_ID`` if set) with discovery kept on this machine.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NODES = ('fan_output', 'force_sensor', 'mocap_relay', 'field_estimator', 'coordinator',
         'sim_tunnel', 'live_view')

#: the child: import the node (timed), run its main until SIGINT after the given seconds
CHILD = r'''
import json, os, signal, sys, threading, time
name, seconds = sys.argv[1], float(sys.argv[2])
t0 = time.process_time()
module = __import__(f'wind_shaper.nodes.{name}', fromlist=['main'])
imported = time.process_time() - t0
state = {}
def stop():
    time.sleep(seconds)
    state['scipy'] = any(m == 'scipy' or m.startswith('scipy.') for m in sys.modules)
    os.kill(os.getpid(), signal.SIGINT)
threading.Thread(target=stop, daemon=True).start()
sys.argv = [name]
code = 0
try:
    code = module.main() or 0
except SystemExit as exc:
    code = exc.code or 0
t = os.times()
print('NODE_START ' + json.dumps({'import_cpu_s': imported, 'cpu_s': t.user + t.system,
                                  'scipy': state.get('scipy'), 'exit': code}), flush=True)
'''


def start_once(name: str, seconds: float, env: dict) -> dict:
    p = subprocess.run([sys.executable, '-c', CHILD, name, str(seconds)], env=env, cwd=ROOT,
                       stdin=subprocess.DEVNULL, capture_output=True, text=True,
                       timeout=seconds + 60)
    for line in p.stdout.splitlines():
        if line.startswith('NODE_START '):
            return json.loads(line[len('NODE_START '):])
    raise RuntimeError(f'{name} printed no figures (exit {p.returncode}):\n{p.stdout[-2000:]}\n'
                       f'{p.stderr[-2000:]}')


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--nodes', default=','.join(NODES), help='comma-separated (default: every node)')
    p.add_argument('--repeats', type=int, default=3, help='starts per node (median taken)')
    p.add_argument('--seconds', type=float, default=5.0, help='how long each start runs [s]')
    p.add_argument('--quick', action='store_true', help='mocap_relay, one start of 2 s')
    p.add_argument('--json', type=Path, default=ROOT / 'bench' / 'out' / 'node_start.json')
    args = p.parse_args(argv)
    if args.quick:
        args.nodes, args.repeats, args.seconds = 'mocap_relay', 1, 2.0
    nodes = [n for n in args.nodes.split(',') if n]
    if not nodes or set(nodes) - set(NODES):
        p.error(f'--nodes: choose from {", ".join(NODES)}')
    if args.repeats < 1 or args.seconds <= 0:
        p.error('--repeats must be >= 1 and --seconds > 0')
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', OPENBLAS_NUM_THREADS='1')
    env.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 101 + 1))
    env.pop('ROS_LOCALHOST_ONLY', None)
    rows = []
    for name in nodes:
        runs = [start_once(name, args.seconds, env) for _ in range(args.repeats)]
        rows.append({'node': name, 'starts': len(runs),
                     'import_cpu_s': float(np.median([r['import_cpu_s'] for r in runs])),
                     'cpu_s': float(np.median([r['cpu_s'] for r in runs])),
                     'scipy': all(r['scipy'] for r in runs), 'exits': [r['exit'] for r in runs]})
    lines = [f'| node | import CPU [s] | CPU over the first {args.seconds:g} s [s] | SciPy loaded |',
             '|---|---|---|---|']
    lines += [f'| {r["node"]} | {r["import_cpu_s"]:.2f} | {r["cpu_s"]:.2f} | '
              f'{"yes" if r["scipy"] else "no"} |' for r in rows]
    text = '\n'.join(lines)
    print(text)
    print(f'(median of {args.repeats} start(s) per node, each alone, ROS_DOMAIN_ID {env["ROS_DOMAIN_ID"]})')
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'rows': rows, 'seconds': args.seconds, 'table': text}, indent=1))
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
