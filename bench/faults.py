"""The fault table: run every fault-injection test (pytest -m fault) and print what each fault
did: survived or not, and how many samples were lost where samples were at stake.

    .venv/bin/python bench/faults.py            # ~3 min; prints a Markdown table
    .venv/bin/python bench/faults.py --json bench/out/faults.json

The rows come from the tests themselves (the ``fault_row`` fixture of test/conftest.py): a test
that fails marks its rows as not survived. Exit code: pytest's.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def collect(pytest_args: list[str]) -> tuple[int, list[dict]]:
    with tempfile.TemporaryDirectory() as tmp:
        rows_path = Path(tmp) / 'rows.jsonl'
        env = dict(os.environ, WIND_SHAPER_FAULT_TABLE=str(rows_path),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        env.setdefault('ROS_DOMAIN_ID', str(os.getpid() % 100 + 1))
        env.pop('ROS_LOCALHOST_ONLY', None)
        code = subprocess.call([sys.executable, '-m', 'pytest', '-q', '-m', 'fault',
                                '-p', 'no:cacheprovider', *pytest_args], cwd=ROOT, env=env)
        rows = [json.loads(line) for line in rows_path.read_text().splitlines()] \
            if rows_path.is_file() else []
    return code, rows


def merge(rows: list[dict]) -> list[dict]:
    """One row per fault (parametrised tests record one per case): survived only if every case
    did; samples lost summed where any case counted them."""
    merged: dict[str, dict] = {}
    for row in rows:
        m = merged.setdefault(row['fault'], dict(row, cases=0, survived=True, samples_lost=None))
        m['cases'] += 1
        m['survived'] = m['survived'] and row['survived']
        if row['samples_lost'] is not None:
            m['samples_lost'] = (m['samples_lost'] or 0) + row['samples_lost']
    return list(merged.values())


def markdown(rows: list[dict]) -> str:
    lines = ['| fault injected | what happened | survived | samples lost |',
             '|---|---|---|---|']
    for r in rows:
        lost = '–' if r['samples_lost'] is None else str(r['samples_lost'])
        lines.append(f"| {r['fault']} | {r['outcome']} | {'yes' if r['survived'] else 'NO'} "
                     f"| {lost} |")
    survived = sum(r['survived'] for r in rows)
    lost = sum(r['samples_lost'] or 0 for r in rows)
    lines.append(f'\n{len(rows)} faults tried, {survived} survived, {lost} samples lost.')
    return '\n'.join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', type=Path, help='also write the rows to this file')
    args, pytest_args = parser.parse_known_args(argv)
    code, rows = collect(pytest_args)
    rows = merge(rows)
    print(markdown(rows))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1) + '\n')
    return code


if __name__ == '__main__':
    raise SystemExit(main())
