"""`wind-shaper iterate | status | cancel`: talk to a running coordinator (the node graph).

    wind-shaper iterate --count 3                # three iterations, a live progress line each
    wind-shaper iterate --target uniform:2.5     # change the run's target, then iterate
    wind-shaper status                           # the coordinator's latest status, then exit
    wind-shaper cancel                           # stop the running iteration at its next step
    wind-shaper set-model improved.yaml          # swap the coordinator's prior, no restart

Each command is a short-lived ROS node; every wait is bounded. rclpy is imported inside the
command functions, so `wind-shaper --help` and the in-process commands work without ROS.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

from ..ros import names

ROS2_EQUIVALENT = (f'ros2 service call /{names.RUN_ITERATION} wind_shaper_msgs/srv/RunIteration '
                   f'"{{target: parabolic}}"')
START_HINT = ('start the graph with `wind-shaper up --sim`, or give the namespace it runs in '
              '(`wind-shaper --namespace NS ...`)')
#: While an iteration runs the coordinator publishes its status at 2 Hz; this long without one
#: means it is gone [s].
STALE_STATUS_S = 10.0
#: An unanswered request to the coordinator goes out again this often [s] (see _Session.call).
RESEND_S = 2.5
#: What the coordinator's refusal says while another procedure runs.
BUSY = 'wait for it'
RUNNING_STATES = ('commanding', 'sweeping', 'estimating', 'updating')


def _not_running(what: str, wait_s: float) -> int:
    print(f'no coordinator answered on {names.resolve(what)} within {wait_s:g} s: {START_HINT}',
          file=sys.stderr)
    return 2


class _Session:
    """A private rclpy context with one node and a single-threaded executor, for a CLI command.

    rclpy's own SIGINT handling is off, so Ctrl-C arrives as KeyboardInterrupt while the context
    still works (iterate uses it to cancel the running iteration)."""

    def __init__(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        # in the graph's namespace ($WIND_SHAPER_NAMESPACE, set by --namespace), where the
        # graph's relative names resolve as the nodes' do
        self.node = rclpy.create_node(f'wind_shaper_cli_{os.getpid()}', context=self.context,
                                      namespace=names.namespace_from_env())
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()

    def spin_until(self, predicate, timeout_s: float, on_tick=None) -> bool:
        """Spin until ``predicate()`` or ``timeout_s`` [s]; ``on_tick()`` runs between spins."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.1, left))
            if on_tick is not None:
                on_tick()
        return True

    def wait_for_service(self, client, timeout_s: float) -> bool:
        return self.spin_until(client.service_is_ready, timeout_s)

    def call(self, client, request, timeout_s: float, *, resend_s: float | None = None,
             accept=lambda response: True):
        """The response ``accept`` takes, or one it refuses when no other request is open (a
        busy server's refusal: the caller decides when to ask again); at ``timeout_s`` [s] the
        last that came, or None. The request goes out again every ``resend_s`` [s] (default
        max(RESEND_S, timeout_s / 4); 0: never): see ``_Resending``. Resend only what may run
        twice, or what a busy server refuses."""
        resend_s = max(RESEND_S, timeout_s / 4) if resend_s is None else resend_s
        calls = _Resending(client, request, resend_s, accept=accept)
        self.spin_until(calls.poll, timeout_s)
        calls.forget()
        return calls.answer

    def interrupt(self, ended, wait_s: float, tty: bool, grace_s: float) -> None:
        """Ctrl-C during a long call: ask the coordinator to cancel what runs, say what it
        answered, and give the call ``grace_s`` [s] to end (``ended()`` true)."""
        from std_srvs.srv import Trigger
        if tty:
            print()
        cancel = self.node.create_client(Trigger, names.CANCEL_ITERATION)
        answer = self.call(cancel, Trigger.Request(), wait_s)
        print('interrupted: ' + (answer.message if answer is not None else
                                 'the coordinator did not answer the cancel request'), file=sys.stderr)
        self.spin_until(ended, grace_s)

    def latest_status(self):
        """Subscribe to the latched status; returns a one-element list updated in place."""
        from wind_shaper_msgs.msg import IterationStatus

        from ..ros import qos
        latest = [None, 0.0]

        def keep(msg):
            latest[0], latest[1] = msg, time.monotonic()

        self.node.create_subscription(IterationStatus, names.STATUS, keep, qos.LATCHED)
        return latest


# ---------------------------------------------------------------------------------- formatting
def _pwm_text(fan_names, pwm) -> str:
    return ' '.join(f'{n}={100 * u:.1f}' for n, u in zip(fan_names, pwm))


def _progress_line(status) -> str:
    bar_len = 20
    done = int(round(bar_len * min(max(status.progress, 0.0), 1.0)))
    samples = f'  {status.samples} samples' if status.samples else ''
    live = ''
    if status.state == 'sweeping' and math.isfinite(getattr(status, 'coverage', math.nan)):
        live = f', coverage {100 * status.coverage:3.0f} %'
        if math.isfinite(status.max_std):
            live += f', largest std {status.max_std:.3f} N'
    return (f'k={status.iteration:<3d} {status.state:<11s} [{"#" * done}{"-" * (bar_len - done)}] '
            f'{100 * status.progress:3.0f}%{samples}{live}')


def format_result(r) -> str:
    """One iteration's answer: k, RMSE before -> predicted after [N], PWMs before -> after [%]."""
    pwm = ' '.join(f'{n} {100 * a:.1f}->{100 * b:.1f}'
                   for n, a, b in zip(r.fan_names, r.pwm_before, r.pwm_after))
    return (f'k={r.iteration:2d}  RMSE {r.rmse_before:.4f} N -> predicted {r.rmse_predicted_after:.4f} N'
            f'  max std {r.max_std:.3f} N\n      PWM% {pwm}\n      record: {r.run_folder}')


def format_status(s) -> str:
    rmse = 'none yet' if math.isnan(s.rmse) else f'{s.rmse:.4f} N'
    where = f'iteration {s.iteration}' if s.iteration >= 0 else 'no iteration yet'
    lines = [f'coordinator: {s.state}, {where} ({100 * s.progress:.0f}%)',
             f'target: {s.target}', f'last RMSE: {rmse}',
             f'commands [%]: {_pwm_text(s.fan_names, s.pwm)}', f'run folder: {s.run_folder}']
    if s.samples:
        lines.insert(2, f'samples: {s.samples}')
    if s.message:
        lines.append(f'message: {s.message}')
    return '\n'.join(lines)


class _Resending:
    """A request to a service, sent again every ``resend_s`` [s] (0: never) while no answer was
    taken and ``may_resend()``; every earlier request still counts. Fast DDS drops a request
    sent before the server matched the caller, or a reply before the server matched its reply
    reader (seen after a restarted coordinator, on a loaded machine), so a request sent once
    can wait in vain. ``poll()`` is true once a response ``accept`` takes came, or one it
    refuses when no other request is open; ``answer`` is the last response that came."""

    def __init__(self, client, request, resend_s: float, *, accept=lambda response: True,
                 may_resend=lambda: True):
        self.client, self.request, self.resend_s = client, request, resend_s
        self.accept, self.may_resend = accept, may_resend
        self.futures = [client.call_async(request)]
        self.sent_at = time.monotonic()
        self.answer = None
        self.done = False

    def poll(self) -> bool:
        for f in [f for f in self.futures if f.done()]:
            self.futures.remove(f)
            self.answer = f.result()
            if self.accept(self.answer) or not self.futures:
                self.done = True
                return True
        # may_resend first, on every poll: it may watch for what ends the resending
        if (self.may_resend() and self.resend_s > 0
                and time.monotonic() - self.sent_at >= self.resend_s):
            self.futures.append(self.client.call_async(self.request))
            self.sent_at = time.monotonic()
        return False

    def forget(self) -> None:
        for f in self.futures:
            self.client.remove_pending_request(f)


class _IterationCall(_Resending):
    """A RunIteration request, sent again every RESEND_S [s] until the coordinator's status
    shows an iteration running since ``started`` (a coordinator that never got the request
    publishes none), and never after: a second request could run a second iteration. A copy
    refused as busy while an earlier request is open is not the answer."""

    def __init__(self, client, request, status, started: float):
        self.status, self.started = status, started
        self.received = False   # an iteration ran since the request went out
        super().__init__(client, request, RESEND_S, accept=lambda r: r.success or BUSY not in r.message,
                         may_resend=self._may_resend)

    def _may_resend(self) -> bool:
        s, heard = self.status
        self.received = self.received or (s is not None and heard >= self.started
                                          and s.state in RUNNING_STATES)
        return not self.received


# ---------------------------------------------------------------------------------- commands
def _cmd_iterate(args) -> int:
    from wind_shaper_msgs.srv import RunIteration
    if args.count < 1:
        print('--count must be >= 1', file=sys.stderr)
        return 2
    tty = sys.stdout.isatty()
    with _Session() as session:
        client = session.node.create_client(RunIteration, names.RUN_ITERATION)
        if not session.wait_for_service(client, args.wait):
            return _not_running(names.RUN_ITERATION, args.wait)
        status = session.latest_status()
        shown = ['']

        def show():
            s = status[0]
            if s is None or s.state not in RUNNING_STATES:
                return  # idle or a past iteration's end: the response tells how this one ended
            line = _progress_line(s)
            if tty:
                print('\r' + line.ljust(72), end='', flush=True)
            elif s.state != shown[0]:
                print(line, flush=True)
            shown[0] = s.state

        for i in range(args.count):
            request = RunIteration.Request(target=args.target if i == 0 else '',
                                           step_gain=args.gain, timeout_s=args.timeout)
            started = time.monotonic()
            calls = _IterationCall(client, request, status, started)
            shown[0] = ''

            def finished_or_gone():
                if calls.poll():
                    return True
                heard = max(status[1], started)
                return time.monotonic() - heard > STALE_STATUS_S

            limit = args.timeout + 60.0 if args.timeout > 0 else 24 * 3600.0
            try:
                session.spin_until(finished_or_gone, limit, on_tick=show)
            except KeyboardInterrupt:
                session.interrupt(calls.poll, args.wait, tty, 10.0)
                return 130
            if tty:
                print('\r' + ' ' * 72 + '\r', end='')
            r = calls.answer if calls.done else None
            calls.forget()
            if r is None:
                print(f'no answer from the coordinator (no status for {STALE_STATUS_S:g} s or the '
                      f'time limit passed): check that it is still running', file=sys.stderr)
                return 2
            if not r.success:
                print(f'iteration refused or failed: {r.message}', file=sys.stderr)
                return 1
            print(format_result(r), flush=True)
    return 0


def _cmd_status(args) -> int:
    with _Session() as session:
        status = session.latest_status()
        if not session.spin_until(lambda: status[0] is not None, args.wait):
            print(f'no coordinator status on {names.resolve(names.STATUS)} within {args.wait:g} s: {START_HINT}',
                  file=sys.stderr)
            return 2
        print(format_status(status[0]))
    return 0


def _cmd_cancel(args) -> int:
    from std_srvs.srv import Trigger
    with _Session() as session:
        client = session.node.create_client(Trigger, names.CANCEL_ITERATION)
        if not session.wait_for_service(client, args.wait):
            return _not_running(names.CANCEL_ITERATION, args.wait)
        answer = session.call(client, Trigger.Request(), args.wait)
        if answer is None:
            print(f'the coordinator did not answer within {args.wait:g} s', file=sys.stderr)
            return 2
        print(answer.message, file=sys.stdout if answer.success else sys.stderr)
        return 0 if answer.success else 1


def _cmd_set_model(args) -> int:
    from wind_shaper_msgs.srv import SetModel
    try:
        text = open(args.model, encoding='utf-8').read()
    except OSError as exc:
        print(f'cannot read the model file {args.model}: {exc.strerror}; give the path of a model '
              f'file (as written by `wind-shaper model add --save` or `wind-shaper calibrate`)',
              file=sys.stderr)
        return 2
    with _Session() as session:
        client = session.node.create_client(SetModel, names.SET_MODEL)
        if not session.wait_for_service(client, args.wait):
            return _not_running(names.SET_MODEL, args.wait)
        # the text, not the path: the coordinator may run on another machine (the path names it)
        answer = session.call(client, SetModel.Request(model_yaml=text, path=str(args.model)), args.wait)
        if answer is None:
            print(f'the coordinator did not answer within {args.wait:g} s', file=sys.stderr)
            return 2
        if not answer.success:  # the coordinator says why, and that the old model stays
            print(answer.message, file=sys.stderr)
            return 1
        print(f'the coordinator now uses {args.model}: {answer.message}')
        return 0


QUERY_EXAMPLE = (f'ros2 service call /{names.QUERY_FIELD} wind_shaper_msgs/srv/QueryField '
                 f'"{{x: [0.0, 0.1], y: [0.0, 0.05]}}"')


def _position(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r} is not a position: give X,Y in metres, e.g. 0.1,-0.05') from None
    return x, y


def _cmd_field(args) -> int:
    from wind_shaper_msgs.srv import QueryField
    points = args.at or [(0.0, 0.0)]
    with _Session() as session:
        client = session.node.create_client(QueryField, names.QUERY_FIELD)
        if not session.wait_for_service(client, args.wait):
            print(f'no field_estimator answered on {names.resolve(names.QUERY_FIELD)} within {args.wait:g} s: '
                  f'{START_HINT}', file=sys.stderr)
            return 2
        answer = session.call(client, QueryField.Request(x=[p[0] for p in points],
                                                         y=[p[1] for p in points]), args.wait)
        if answer is None:
            print(f'the field_estimator did not answer within {args.wait:g} s', file=sys.stderr)
            return 2
        if not answer.success:
            print(answer.message, file=sys.stderr)
            return 1
        print(f'estimated field of iteration {answer.iteration} (tunnel frame):')
        for (x, y), f, sd in zip(points, answer.force, answer.std):
            print(f'  ({x:+.3f}, {y:+.3f}) m: {f:.3f} N +- {sd:.3f} N')
        return 0


def _wait_arg(p) -> None:
    p.add_argument('--wait', type=float, default=5.0, metavar='S',
                   help='how long to wait for the coordinator to answer [s] (default 5)')


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'iterate', help='run iterations on the node graph (the coordinator)',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Call the coordinator\'s run_iteration service N times, with a live progress '
                    'line from its status topic, and print each result (k, RMSE before -> '
                    'predicted after, PWMs). Ctrl-C cancels the running iteration.',
        epilog=f'On a full ROS 2 install the same call is:\n  {ROS2_EQUIVALENT}')
    p.add_argument('--target', default='',
                   help='change the run\'s target first: uniform[:F] | gaussian[@FAN] | parabolic | '
                        'expr:<f(x,y)> | csv:<file> (default: keep it)')
    p.add_argument('--gain', type=float, default=0.0,
                   help='step gain, lambda_k = gain / (k + 1) (default: shaping.yaml)')
    p.add_argument('--timeout', type=float, default=0.0, metavar='S',
                   help='iteration timeout [s] (default: the coordinator\'s iteration_timeout_s)')
    p.add_argument('--count', type=int, default=1, metavar='N', help='iterations to run (default 1)')
    _wait_arg(p)
    p.set_defaults(func=_cmd_iterate)

    p = subparsers.add_parser(
        'status', help='print the coordinator\'s latest status and exit',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f'On a full ROS 2 install: ros2 topic echo --once /{names.STATUS}')
    _wait_arg(p)
    p.set_defaults(func=_cmd_status)

    p = subparsers.add_parser(
        'cancel', help='stop the running iteration at its next step (the fans keep the last '
                       'completed iteration\'s commands)',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f'On a full ROS 2 install: ros2 service call /{names.CANCEL_ITERATION} '
               f'std_srvs/srv/Trigger')
    _wait_arg(p)
    p.set_defaults(func=_cmd_cancel)

    p = subparsers.add_parser(
        'set-model', help='swap the running coordinator\'s prior model for a model file, '
                          'without a restart (from the next iteration on)',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f'On a full ROS 2 install: ros2 service call /{names.SET_MODEL} '
               f'wind_shaper_msgs/srv/SetModel "{{path: /abs/path/improved.yaml}}"')
    p.add_argument('model', help='a model file (YAML), e.g. from `wind-shaper model add --save`')
    _wait_arg(p)
    p.set_defaults(func=_cmd_set_model)

    p = subparsers.add_parser(
        'field', help='the estimated force (and its std) at positions of the tunnel, from the '
                      'latest field estimate (what a robot uses as feed-forward)',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f'On a full ROS 2 install: {QUERY_EXAMPLE}')
    p.add_argument('--at', action='append', type=_position, metavar='X,Y',
                   help='a position [m, tunnel frame]; repeat for more (default: the axis)')
    _wait_arg(p)
    p.set_defaults(func=_cmd_field)


__all__ = ['register', 'format_result', 'format_status', 'ROS2_EQUIVALENT', 'QUERY_EXAMPLE']
