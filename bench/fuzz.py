"""The fuzz tier at length: every request and file target of test/fuzz, many examples each.

    .venv/bin/python bench/fuzz.py                     # 500 examples per target; ~10-20 min
    .venv/bin/python bench/fuzz.py --examples 5000 --only 'model file'
    .venv/bin/python bench/fuzz.py --examples 3 --json out.json   # what CI runs (seconds)

Prints, per target: the examples tried, how many ended in a result and how many in a refusal,
the slowest example [s] and the process's resident memory before and after [MB]; a crash (any
exception other than a refusal) is printed with the example that caused it and makes the exit
code 1. The targets are test/fuzz/targets.py's (the checks each node makes, then the parsing);
--json writes the figures. Figures depend on the host: a measurement, not a test.
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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--examples', type=int, default=500, help='examples per target (default 500)')
    p.add_argument('--only', action='append', default=[], help='run only this target (repeatable)')
    p.add_argument('--seed', type=int, default=0, help='hypothesis seed (default 0)')
    p.add_argument('--json', type=Path, help='write the figures here')
    args = p.parse_args(argv)
    import warnings
    warnings.simplefilter('ignore')   # a damaged folder's warnings are expected, by the thousand
    from targets import NAMES, strategies
    unknown = sorted(set(args.only) - set(NAMES))
    if unknown:
        p.error(f'unknown targets {unknown}; the targets are {NAMES}')
    built = strategies()
    start = rss_mb()
    rows = []
    print(f'{"target":<22} {"tried":>6} {"result":>7} {"refused":>8} {"slowest s":>10} '
          f'{"total s":>8} {"RSS MB":>14}')
    for name in args.only or NAMES:
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
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'examples': args.examples, 'seed': args.seed,
                                         'rss_growth_MB': round(grown, 1), 'targets': rows},
                                        indent=1))
    return 1 if any(r['crash'] for r in rows) else 0


if __name__ == '__main__':
    raise SystemExit(main())
