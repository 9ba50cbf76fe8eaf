"""Kill loop: how often the node graph fails to recover from a node killed in the middle of a
sweep. One `wind-shaper up --sim` graph; each cycle starts an iteration, SIGKILLs one node
(the ones named, in turn) 1 s into its sweep, waits for the supervisor's restart, and counts
the cycle good when the iteration completes and the field query answers. After two kills of
each node the graph starts afresh (the restart backoff doubles per kill).

    .venv/bin/python bench/kill_loop.py --cycles 40                       # about 12 min
    .venv/bin/python bench/kill_loop.py --cycles 40 --load 2              # two busy processes beside it
    .venv/bin/python bench/kill_loop.py --nodes mocap_relay --cycles 20 --json bench/out/kill_loop.json

A rare failure (one cycle in tens) is what this measures: choose the transport and executor of
the nodes with it, not with the fault tests, which kill each node once. A failed cycle prints
the killed node's lines and the coordinator's last ones. Exit code 1 when a cycle failed.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test' / 'graph'))
from up_driver import UP_LINE, Up, node_pids  # noqa: E402

SWEEP_S = 3.0
#: kills of one node before the graph is started afresh
KILLS_PER_GRAPH = 2


def _burn() -> None:
    while True:
        pass


def _cli(root: Path, env: dict, *args: str, timeout_s: float = 200) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'wind_shaper.cli.main', *args], cwd=root,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


class Loop:
    def __init__(self, root: Path, env: dict, deaf_after: float = 30.0):
        self.root, self.env, self.deaf_after = root, env, deaf_after
        self.up = Up(env, root, '--run-name', 'kill_loop', '--startup-timeout', '60',
                     '--hang-after', '8', '--deaf-after', str(deaf_after), '--max-restarts', '100000',
                     '--set', f'coordinator.sweep_duration_s={SWEEP_S}',
                     '--set', 'coordinator.settle_s=0.3', '--set', 'coordinator.max_sweeps=5',
                     mocap_rate_hz=None)   # the sim's own pose rate, as `wind-shaper up --sim` runs
        self.pids = node_pids(self.up.wait_line(UP_LINE.pattern, 90))
        self.seen = 0

    def new_lines(self) -> list[str]:
        return self.up.output().splitlines()[self.seen:]

    def wait_for(self, pattern: str, timeout_s: float):
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in self.new_lines():
                m = regex.search(line)
                if m:
                    return m
            time.sleep(0.05)
        return None

    def iterate(self) -> tuple[int, str]:
        call = _cli(self.root, self.env, 'iterate', '--wait', '30', '--timeout', '90')
        out, _ = call.communicate(timeout=200)
        return call.returncode, out

    def cycle(self, node: str) -> dict:
        self.seen = len(self.up.output().splitlines())
        call = _cli(self.root, self.env, 'iterate', '--wait', '30', '--timeout', '90')
        started = self.wait_for(r'\[sweeping\] iteration \d+', 60) is not None
        time.sleep(1.0)
        # the node may have been restarted since (e.g. found hung on a busy machine)
        restarts = re.findall(rf'restarting {node} \(\d+ of \d+\): pid (\d+)', self.up.output())
        if restarts:
            self.pids[node] = int(restarts[-1])
        try:
            os.kill(self.pids[node], signal.SIGKILL)
        except ProcessLookupError:
            pass    # it died on its own: the restart below is still awaited
        m = self.wait_for(rf'restarting {node} \(\d+ of \d+\): pid (\d+)', 30)
        if m:
            self.pids[node] = int(m.group(1))
        out, _ = call.communicate(timeout=200)
        query = subprocess.run([sys.executable, '-m', 'wind_shaper.cli.main', 'field', '--wait',
                                '10', '--at=0,0'], cwd=self.root, env=self.env,
                               capture_output=True, text=True, timeout=60)
        row = {'node': node, 'sweep_started': started, 'restarted': m is not None,
               'iterate': call.returncode, 'field_query': query.returncode}
        row['ok'] = started and m is not None and call.returncode == 0 and query.returncode == 0
        if not row['ok'] and self.deaf_after > 0:
            # the supervisor restarts a node that answers nothing for --deaf-after: does the
            # graph answer again once that has had its time?
            deadline = time.monotonic() + self.deaf_after + 30
            while time.monotonic() < deadline:
                later = subprocess.run([sys.executable, '-m', 'wind_shaper.cli.main', 'field', '--wait',
                                        '5', '--at=0,0'], cwd=self.root, env=self.env,
                                       capture_output=True, text=True, timeout=60)
                if later.returncode == 0:
                    break
            row['answers_later'] = later.returncode == 0
            row['deaf_restarted'] = any('deaf to the graph' in line for line in self.new_lines())
        if not row['ok']:
            # where is each node waiting? (the nodes print their threads' stacks on SIGUSR1)
            for pid in list(self.pids.values()):
                try:
                    os.kill(pid, signal.SIGUSR1)
                except ProcessLookupError:
                    pass
            time.sleep(2.0)
            row['stacks'] = [line for line in self.new_lines()
                             if 'File "' in line or 'Thread 0x' in line or 'Current thread' in line]
            lines = self.new_lines()
            row['lines'] = ([line for line in lines if f'[{node}' in line or node in line][-12:]
                            + [line for line in lines if '[coordinator' in line][-6:])
            row['iterate_output'] = out[-800:]
        return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--cycles', type=int, default=40)
    ap.add_argument('--nodes', default='field_estimator,mocap_relay',
                    help='nodes killed in turn (comma-separated)')
    ap.add_argument('--load', type=int, default=0, help='busy processes run beside the graph')
    ap.add_argument('--domain', default=os.environ.get('ROS_DOMAIN_ID') or str(os.getpid() % 90 + 10),
                    help='ROS_DOMAIN_ID (default: the environment\'s, else one from the process id)')
    ap.add_argument('--deaf-after', type=float, default=30.0,
                    help="the graph's --deaf-after [s] (0: off); a cycle that failed then counts "
                         "whether the graph answered again within that time + 30 s")
    ap.add_argument('--json', type=Path, default=None)
    args = ap.parse_args(argv)
    nodes = [n for n in args.nodes.split(',') if n]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=args.domain)
    env.pop('ROS_LOCALHOST_ONLY', None)
    burners = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(args.load)]
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix='kill_loop') as tmp:
        loop = Loop(Path(tmp), env, args.deaf_after)
        try:
            code, out = loop.iterate()
            if code != 0:
                print(f'the first iteration, before any kill, failed:\n{out[-2000:]}')
                return 1
            for b in burners:
                b.start()
            for i in range(args.cycles):
                if i and i % (KILLS_PER_GRAPH * len(nodes)) == 0:
                    # the supervisor's restart backoff doubles per node (1, 2, 4, 8 s, reset
                    # after 300 s of running): a fifth kill within minutes would measure it
                    loop.up.kill()
                    loop = Loop(Path(tmp), env, args.deaf_after)
                row = loop.cycle(nodes[i % len(nodes)])
                rows.append(row)
                print(f"cycle {i}: {row['node']} killed: "
                      f"{'recovered' if row['ok'] else 'NOT recovered'} (iterate exit "
                      f"{row['iterate']}, field query exit {row['field_query']})", flush=True)
                if not row['ok']:
                    if 'answers_later' in row:
                        print(f"    restarted as deaf: {row['deaf_restarted']}; the graph answered "
                              f"again within --deaf-after + 30 s: {row['answers_later']}", flush=True)
                    print('\n'.join('    ' + line for line in row['lines']), flush=True)
                    print('\n'.join('    ' + line for line in row['stacks']), flush=True)
        finally:
            for b in burners:
                b.terminate()
            loop.up.kill()
    failed = sum(not r['ok'] for r in rows)
    for node in nodes:
        mine = [r for r in rows if r['node'] == node]
        print(f"{node}: {sum(r['ok'] for r in mine)} of {len(mine)} kills recovered")
    print(f'{len(rows) - failed} of {len(rows)} cycles recovered (load: {args.load} busy processes)')
    later = [r for r in rows if not r['ok'] and 'answers_later' in r]
    if later:
        print(f"of the {len(later)} that did not: {sum(r['deaf_restarted'] for r in later)} restarted "
              f"as deaf, {sum(r['answers_later'] for r in later)} answered again within "
              f"--deaf-after + 30 s")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'load': args.load, 'rows': rows}, indent=1) + '\n')
    return 1 if failed else 0


if __name__ == '__main__':
    raise SystemExit(main())
