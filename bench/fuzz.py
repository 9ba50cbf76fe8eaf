"""The fuzz tier at length: every request and file target of test/fuzz, many examples each.

    .venv/bin/python bench/fuzz.py                     # 500 examples per target; ~10-20 min
    .venv/bin/python bench/fuzz.py --examples 5000 --only 'model file'
    .venv/bin/python bench/fuzz.py --examples 3 --json out.json   # what CI runs (seconds)
    .venv/bin/python bench/fuzz.py --coordinator 200 --only none   # the coordinator's memory

Prints, per target: the examples tried, how many ended in a result and how many in a refusal,
the slowest example [s] and the process's resident memory before and after [MB]; a crash (any
exception other than a refusal) is printed with the example that caused it and makes the exit
code 1. The targets are test/fuzz/targets.py's (the checks each node makes, then the parsing);
--json writes the figures. Figures depend on the host: a measurement, not a test.

--coordinator N starts a coordinator node as a process of its own (no rig: a request that
would move fans fails after a short wait) and sends it N examples of each of its requests
(set_model, run_iteration, collect, hold_point, from the same strategies) through its services,
then prints its resident memory before and after (the target: it grows at most 50 MB) and the
slowest answer. It runs on $ROS_DOMAIN_ID (default 85), discovery on this machine only.
"""
from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test' / 'fuzz'))


def rss_mb() -> float:
    with open('/proc/self/statm') as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def fuzz(name: str, strategy, target, examples: int, seed: int) -> dict:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    counts = {'ok': 0, 'refused': 0}
    slowest = [0.0]

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def run(data):
        example = data.draw(strategy)
        t0 = time.perf_counter()
        outcome = target(example)
        slowest[0] = max(slowest[0], time.perf_counter() - t0)
        counts[outcome] += 1

    from hypothesis import seed as fix_seed
    before = rss_mb()
    t0 = time.perf_counter()
    crash = ''
    try:
        fix_seed(seed)(run)()
    except Exception as exc:  # noqa: BLE001 - a crash is the finding, printed with its example
        crash = f'{type(exc).__name__}: {str(exc)[:2000]}'
    return {'target': name, 'tried': counts['ok'] + counts['refused'], **counts,
            'slowest_s': round(slowest[0], 3), 'total_s': round(time.perf_counter() - t0, 1),
            'rss_before_MB': round(before, 1), 'rss_after_MB': round(rss_mb(), 1), 'crash': crash}


def process_rss_mb(pid: int) -> float:
    with open(f'/proc/{pid}/statm') as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def fuzz_coordinator(examples: int, seed: int) -> dict:
    """The coordinator's resident memory over ``examples`` hostile requests of each kind,
    sent through its services (see the module docstring)."""
    import os
    import subprocess
    import tempfile
    import threading

    import rclpy
    from hypothesis import HealthCheck, given, settings
    from hypothesis import seed as fix_seed
    from hypothesis import strategies as st
    from rclpy.executors import SingleThreadedExecutor
    from std_srvs.srv import Trigger
    from wind_shaper_msgs.srv import Collect, HoldPoint, RunIteration, SetModel

    from targets import MAX_MESSAGE, strategies
    from wind_shaper.ros import names

    built = strategies()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=os.environ.get('ROS_DOMAIN_ID') or '85')
    env.pop('ROS_LOCALHOST_ONLY', None)
    root = Path(tempfile.mkdtemp(prefix='fuzz-coordinator-'))
    log = open(root / 'coordinator.log', 'wb')
    params = {'run_root': str(root / 'runs'), 'apply_timeout_s': 0.5, 'settle_s': 0.0,
              'service_timeout_s': 0.5, 'iteration_timeout_s': 5.0, 'sweep_service': "''",
              'republish_hz': 2.0}
    argv = [sys.executable, '-m', 'wind_shaper.nodes.coordinator', '--ros-args']
    for k, v in params.items():
        argv += ['-p', f'{k}:={v}']
    child = subprocess.Popen(argv, env=env, cwd=root, stdin=subprocess.DEVNULL, stdout=log,
                             stderr=subprocess.STDOUT, start_new_session=True)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('fuzz_coordinator_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    clients = {what: node.create_client(kind, name) for what, kind, name in (
        ('set_model', SetModel, names.SET_MODEL), ('run_iteration', RunIteration, names.RUN_ITERATION),
        ('collect', Collect, names.COLLECT), ('hold_point', HoldPoint, names.HOLD_POINT),
        ('cancel', Trigger, names.CANCEL_ITERATION))}
    counts = {'answered': 0, 'ok': 0, 'refused': 0, 'unanswered': 0}
    slowest = [0.0]

    def call(what, request, timeout_s=30.0):
        client = clients[what]
        t0 = time.perf_counter()
        future = client.call_async(request)
        while not future.done() and time.perf_counter() - t0 < timeout_s:
            time.sleep(0.002)
        if not future.done():
            client.remove_pending_request(future)
            counts['unanswered'] += 1
            return None
        slowest[0] = max(slowest[0], time.perf_counter() - t0)
        response = future.result()
        counts['answered'] += 1
        counts['ok' if response.success else 'refused'] += 1
        assert len(getattr(response, 'message', '')) < MAX_MESSAGE, response.message[:300]
        return response

    def request(what, example):
        if what == 'set_model':
            text, path = example
            return SetModel.Request(model_yaml=text.encode('utf-8', 'replace').decode(), path=path)
        if what == 'run_iteration':
            return RunIteration.Request(target=example.encode('utf-8', 'replace').decode(),
                                        timeout_s=2.0)
        if what == 'collect':
            name, design, fans, commands, labels = example
            clean = lambda t: t.encode('utf-8', 'replace').decode()   # noqa: E731
            return Collect.Request(name=clean(name), design=clean(design),
                                   fan_names=[clean(f) for f in fans],
                                   commands=[float(c) for c in commands],
                                   labels=[clean(x) for x in labels], timeout_s=2.0)
        fans, pwm = example
        return HoldPoint.Request(fan_names=[f.encode('utf-8', 'replace').decode() for f in fans],
                                 pwm=[float(u) for u in pwm], timeout_s=1.0)

    strategy_of = {'set_model': 'set_model request', 'run_iteration': 'run_iteration target',
                   'collect': 'collect request', 'hold_point': 'hold_point request'}
    try:
        deadline = time.monotonic() + 60
        while not all(c.service_is_ready() for c in clients.values()):
            if time.monotonic() > deadline or child.poll() is not None:
                log.flush()
                tail = (root / 'coordinator.log').read_text(errors='replace')[-3000:]
                raise RuntimeError(f'the coordinator did not come up:\n{tail}')
            time.sleep(0.1)
        # warm up (the first requests import and allocate what every later one reuses)
        for what in strategy_of:
            call(what, request(what, built[strategy_of[what]][0].example()))
        time.sleep(1.0)
        counts.update(answered=0, ok=0, refused=0, unanswered=0)
        slowest[0] = 0.0
        before = process_rss_mb(child.pid)
        t0 = time.perf_counter()
        for what, target in strategy_of.items():
            @settings(max_examples=examples, deadline=None, database=None,
                      suppress_health_check=list(HealthCheck))
            @given(st.data())
            def run(data):
                answer = call(what, request(what, data.draw(built[target][0])))
                if answer is not None and answer.success and what != 'set_model':
                    call('cancel', Trigger.Request())
            fix_seed(seed)(run)()
        after = process_rss_mb(child.pid)
        return {'requests': counts['answered'] + counts['unanswered'], **counts,
                'slowest_answer_s': round(slowest[0], 3), 'total_s': round(time.perf_counter() - t0, 1),
                'rss_before_MB': round(before, 1), 'rss_after_MB': round(after, 1),
                'rss_growth_MB': round(after - before, 1), 'alive': child.poll() is None}
    finally:
        stop.set()
        spinner.join(5.0)
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()
        context.try_shutdown()
        if child.poll() is None:
            child.send_signal(2)
            try:
                child.wait(10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait(5)
        log.close()
        import shutil
        shutil.rmtree(root, ignore_errors=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--examples', type=int, default=500, help='examples per target (default 500)')
    p.add_argument('--only', action='append', default=[], help='run only this target (repeatable)')
    p.add_argument('--seed', type=int, default=0, help='hypothesis seed (default 0)')
    p.add_argument('--json', type=Path, help='write the figures here')
    p.add_argument('--coordinator', type=int, default=0, metavar='N',
                   help='also send N examples of each request to a coordinator process and '
                        'print its memory (default 0: not)')
    args = p.parse_args(argv)
    import warnings
    warnings.simplefilter('ignore')   # a damaged folder's warnings are expected, by the thousand
    from targets import NAMES, strategies
    only_none = args.only == ['none']   # --only none: no file or request target, only --coordinator
    if only_none:
        args.only = []
    unknown = sorted(set(args.only) - set(NAMES))
    if unknown:
        p.error(f'unknown targets {unknown}; the targets are {NAMES}')
    built = strategies()
    start = rss_mb()
    rows = []
    print(f'{"target":<22} {"tried":>6} {"result":>7} {"refused":>8} {"slowest s":>10} '
          f'{"total s":>8} {"RSS MB":>14}')
    for name in [] if only_none else (args.only or NAMES):
        row = fuzz(name, *built[name], args.examples, args.seed)
        rows.append(row)
        print(f'{name:<22} {row["tried"]:>6} {row["ok"]:>7} {row["refused"]:>8} '
              f'{row["slowest_s"]:>10.3f} {row["total_s"]:>8.1f} '
              f'{row["rss_before_MB"]:>6.0f} -> {row["rss_after_MB"]:<6.0f}', flush=True)
        if row['crash']:
            print(f'  CRASH: {row["crash"]}')
    grown = rss_mb() - start
    print(f'resident memory grew {grown:.1f} MB over the whole run '
          f'({sum(r["tried"] for r in rows)} examples)')
    node = None
    if args.coordinator > 0:
        node = fuzz_coordinator(args.coordinator, args.seed)
        print(f'coordinator: {node["requests"]} hostile requests through its services, '
              f'{node["ok"]} results, {node["refused"]} refusals, {node["unanswered"]} unanswered '
              f'(slowest answer {node["slowest_answer_s"]:.2f} s, {node["total_s"]:.0f} s in all); '
              f'resident memory {node["rss_before_MB"]:.0f} -> {node["rss_after_MB"]:.0f} MB '
              f'({node["rss_growth_MB"]:+.1f} MB; target: at most +50 MB)'
              + ('' if node['alive'] else '; THE COORDINATOR DIED'))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'examples': args.examples, 'seed': args.seed,
                                         'rss_growth_MB': round(grown, 1), 'targets': rows,
                                         'coordinator': node}, indent=1))
    failed = node is not None and (not node['alive'] or node['unanswered'] > 0)
    return 1 if any(r['crash'] for r in rows) or failed else 0


if __name__ == '__main__':
    raise SystemExit(main())
