"""`wind-shaper calibrate --held`: the paper's held-plate batch, guided, through the node graph.

For each point of the batch the command says which fan runs at which command and where to hold
the plate; the coordinator's hold_point service applies the commands, brings the plate there
(a motion stage) or waits for a person to, confirms with the mocap pose that the plate is within
tolerance and still, and records the force. Each point goes to the batch folder as it is done
(``storage.HeldBatch``), so the same command again resumes where it stopped. At a terminal:
Enter records, ``s`` skips the point, ``r`` redoes the previous one, ``q`` stops (resume
later). Without a terminal (or with ``--auto``) every point is recorded in turn. When no point
is left, the paper's prior is fitted to the batch and written with its RMSE and parameter
uncertainties.
"""
from __future__ import annotations

import sys
import time
from dataclasses import asdict
from pathlib import Path

from ..ros import names
from .service import BUSY, _not_running, _Session

#: Tries of a point that fails (the plate not still in time, it moved) before moving on.
AUTO_TRIES = 2
#: A point's request goes out again this often while no answer came [s].
HOLD_RESEND_S = 15.0


def _plan(setup, args):
    from ..model import CalibrationPlan
    from ..coordination.held import held_points
    plan = CalibrationPlan(samples_per_point=args.samples)
    if args.levels:
        plan = CalibrationPlan(levels=tuple(args.levels), spread_level=plan.spread_level,
                               offsets=plan.offsets, samples_per_point=args.samples)
    if args.offsets:
        plan = CalibrationPlan(levels=plan.levels, spread_level=plan.spread_level,
                               offsets=tuple(args.offsets), samples_per_point=args.samples)
    # the paper's batch runs fans to 80 %; no fan gets more than the configured range allows
    b = setup.shaping.bounds
    allowed = tuple(u for u in plan.levels if u == 0 or b.u_min <= u <= b.u_max)
    dropped = len(plan.levels) - len(allowed)
    if dropped:
        print(f'note: {dropped} level(s) of the batch lie outside shaping.yaml\'s range '
              f'[{b.u_min:g}, {b.u_max:g}] and are left out', flush=True)
    spread = min(max(plan.spread_level, b.u_min), b.u_max)
    plan = CalibrationPlan(levels=allowed, spread_level=spread, offsets=plan.offsets,
                           samples_per_point=plan.samples_per_point)
    return held_points(setup.geometry, plan)


def _floats(text: str) -> list:
    try:
        return [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        import argparse
        raise argparse.ArgumentTypeError(f'give numbers separated by commas, e.g. 0,0.4,0.8; got {text!r}')


def run_held(setup, args) -> int:
    from wind_shaper_msgs.srv import HoldPoint
    from std_srvs.srv import Trigger

    from ..app import save_fit
    from ..model import fit_model, paper_prior
    from ..storage import RECORDED, SKIPPED, HeldBatch
    points, outside = _plan(setup, args)
    fans = setup.geometry.fans
    batch = HeldBatch.open(args.batch_root, args.batch, fans.names, [asdict(p) for p in points])
    interactive = sys.stdin.isatty() and not args.auto
    todo = batch.pending()
    print(f'held-plate batch {batch.folder}: {len(points)} points ({outside} left out: outside the '
          f'sweep disc), {len(points) - len(todo)} done, {len(todo)} to record; tolerance '
          f'{100 * args.tolerance:.1f} cm, {args.samples} poses each', flush=True)
    with _Session() as session:
        client = session.node.create_client(HoldPoint, names.HOLD_POINT)
        if todo and not session.wait_for_service(client, args.wait):
            return _not_running(names.HOLD_POINT, args.wait)
        queue, previous, tries = list(todo), None, {}
        busy_until = time.monotonic() + args.timeout
        while queue:
            i = queue[0]
            p = points[i]
            done = len(points) - len(batch.pending())
            print(f'[{done + 1}/{len(points)}] {p.label}: hold the plate at ({p.x:+.3f}, {p.y:+.3f}) m',
                  flush=True)
            if interactive:
                key = input('  Enter = record, s = skip, r = redo the previous point, q = stop here: ')
                key = key.strip().lower()
                if key == 'q':
                    break
                if key == 's':
                    batch.append(i, SKIPPED)
                    queue.pop(0)
                    continue
                if key == 'r' and previous is not None:
                    queue.insert(0, previous)
                    continue
            request = HoldPoint.Request(fan_names=list(fans.names), pwm=[float(u) for u in p.pwm],
                                        x=p.x, y=p.y, tolerance_m=args.tolerance,
                                        samples=args.samples, timeout_s=args.timeout)
            try:
                # asked again while no answer came (a lost request or reply); a point still
                # recording refuses the copies as busy, and its own answer is taken
                answer = session.call(client, request, args.timeout + 60.0, resend_s=HOLD_RESEND_S,
                                      accept=lambda r: BUSY not in r.message)
            except KeyboardInterrupt:
                cancel = session.node.create_client(Trigger, names.CANCEL_ITERATION)
                session.call(cancel, Trigger.Request(), args.wait)
                print('\ninterrupted: the points recorded so far are kept; run the same command '
                      'again to resume', file=sys.stderr)
                return 130
            if answer is None:
                print('no answer from the coordinator: check it, then run the same command again to '
                      'resume', file=sys.stderr)
                return 2
            if answer.success:
                batch.append(i, RECORDED, force_mean=answer.force_mean, force_std=answer.force_std,
                             n=int(answer.n), x_mean=answer.x_mean, y_mean=answer.y_mean)
                print(f'  recorded: {answer.message}', flush=True)
                previous = queue.pop(0)
                continue
            if BUSY in answer.message and time.monotonic() < busy_until:
                time.sleep(1.0)   # the coordinator still finishes another request (a killed caller's)
                continue
            print(f'  not recorded: {answer.message}', file=sys.stderr, flush=True)
            if not interactive:
                tries[i] = tries.get(i, 0) + 1
                if tries[i] >= AUTO_TRIES:
                    queue.pop(0)   # left pending: the next run tries it again
    left = batch.pending()
    if left:
        print(f'{len(left)} point(s) still to record: run the same command again to resume',
              file=sys.stderr)
        return 1
    data = batch.measurements()
    if len(data.forces) < 12:
        print(f'only {len(data.forces)} points were recorded (the rest skipped): too few to fit '
              f'the prior; redo the batch under another --batch name', file=sys.stderr)
        return 1
    fit = fit_model(paper_prior(fans), data)
    out = args.out or Path('models') / f'{args.batch}.yaml'
    save_fit(out, fit, source=f'held-plate batch {batch.folder} ({len(data.forces)} points)')
    print(f'fitted {fit.model!r} on {len(data.forces)} held points; RMSE {fit.rmse:.4f} N')
    for name, value, std in zip(fit.names, fit.theta, fit.theta_std):
        print(f'  {fit.model.display_name(name):<32} {value:10.4f} +- {std:.4f}')
    print(f'written to {out}; load it into the running coordinator with `wind-shaper set-model {out}`')
    return 0


def add_arguments(p) -> None:
    g = p.add_argument_group('held-plate batch (--held)')
    g.add_argument('--held', action='store_true',
                   help='the paper\'s held-plate batch, guided point by point through the node graph')
    g.add_argument('--batch', default='held-batch', metavar='NAME',
                   help='batch folder under --batch-root; the same name resumes (default held-batch)')
    g.add_argument('--batch-root', type=Path, default=Path('runs'), metavar='DIR',
                   help='where batch folders live (default runs)')
    g.add_argument('--samples', type=int, default=20, help='poses recorded per point (default 20)')
    g.add_argument('--tolerance', type=float, default=0.01, metavar='M',
                   help='how far from the point, and how much motion, counts as held [m] (default 0.01)')
    g.add_argument('--timeout', type=float, default=120.0, metavar='S',
                   help='wait at most this long for the plate at each point [s] (default 120)')
    g.add_argument('--levels', type=_floats, default=None, metavar='U,U,...',
                   help='commands of the over-hub points (default 0, 0.05, ..., 0.8)')
    g.add_argument('--offsets', type=_floats, default=None, metavar='M,M,...',
                   help='plate offsets around each hub [m] (default 0.05,0.10,0.15,0.20)')
    g.add_argument('--auto', action='store_true',
                   help='record every point in turn without asking (a motion stage places the plate)')
    g.add_argument('--wait', type=float, default=5.0, metavar='S',
                   help='how long to wait for the coordinator to answer [s] (default 5)')


__all__ = ['run_held', 'add_arguments']
