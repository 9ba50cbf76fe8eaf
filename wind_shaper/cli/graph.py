"""`wind-shaper up`: the node graph as separate processes (thin layer over
``wind_shaper.supervisor``; rclpy is imported only when it runs).

    wind-shaper up --sim                                   # the graph on the simulated tunnel
    wind-shaper up --sim --iterations 12 --target parabolic  # ... and run the loop, then report

Without ``--iterations`` it brings the graph up, prints what to type in a second terminal and
supervises until Ctrl-C. With ``--iterations N --target T`` it calls the coordinator's
``run_iteration`` service N times, writes the report folder from the run folder, and stops.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import yaml

from ..core.safe_yaml import load_yaml

#: The coordinator parameter that names the run folder (``--run-name``).
RUN_NAME_PARAM = 'run_name'


# ---------------------------------------------------------------------------------- arguments
def _setting(text: str) -> tuple[str, str, object]:
    """``NODE.PARAM=VALUE`` -> (node, param, value typed as YAML)."""
    key, sep, raw = text.partition('=')
    node, dot, name = key.partition('.')
    if not (sep and dot and node and name):
        raise argparse.ArgumentTypeError(f'{text!r}: write NODE.PARAM=VALUE, e.g. '
                                         f'coordinator.sweep_duration_s=3')
    try:
        value = load_yaml(raw, 'the value') if raw.strip() else ''
    except yaml.YAMLError:
        value = raw
    return node, name, raw if value is None else value


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be > 0; got {text}')
    return value


def register(subparsers) -> None:
    p = subparsers.add_parser(
        'up', help='start the node graph (one process per node) and supervise it',
        description='Start fan_output, force_sensor, mocap_relay, field_estimator and coordinator '
                    '(and sim_tunnel with --sim) as separate processes, wait until all are in '
                    'the ROS graph, and supervise them until Ctrl-C. With --iterations and '
                    '--target, run the shaping loop through the graph, write the report and stop.')
    p.add_argument('--sim', action='store_true',
                   help='also start sim_tunnel, the simulated rig on 127.0.0.1')
    p.add_argument('--config', type=Path, default=None,
                   help='config folder with tunnel.yaml, shaping.yaml, ... and <node>.yaml per node '
                        '(default: the shipped one; a missing <node>.yaml falls back to it)')
    p.add_argument('--run-name', default=None,
                   help='run folder name for the coordinator (resumes it if it exists)')
    p.add_argument('--iterations', type=int, default=None, metavar='N',
                   help='run N iterations through the graph, write the report, then stop')
    p.add_argument('--target', default=None,
                   help='target for --iterations: uniform[:F] | gaussian[@FAN] | parabolic | '
                        'expr:<f(x,y)> | csv:<file>')
    p.add_argument('--report', type=Path, default=None,
                   help='report folder for --iterations (default: <run folder>/report)')
    p.add_argument('--set', dest='settings', action='append', type=_setting, default=[],
                   metavar='NODE.PARAM=VALUE',
                   help='override one node parameter, e.g. coordinator.sweep_duration_s=3; repeat')
    p.add_argument('--no-restart', action='store_true', help='do not restart a node that dies')
    p.add_argument('--max-restarts', type=int, default=3,
                   help='restarts per node before giving up (default 3; backoff 1, 2, 4 s)')
    p.add_argument('--hang-after', type=float, default=20.0, metavar='S',
                   help='restart a node whose executor has not run for this long: hung (default '
                        '20 s; 0 = never) [s]')
    p.add_argument('--deaf-after', type=float, default=30.0, metavar='S',
                   help='restart a node that is running but has answered no call for this long: '
                        'deaf to the graph (default 30 s; 0 = never; up asks each node every '
                        '3 s) [s]')
    p.add_argument('--startup-timeout', type=_positive, default=60.0, metavar='S',
                   help='longest wait for every node to appear in the graph [s] (default 60)')
    p.add_argument('--iteration-timeout', type=_positive, default=600.0, metavar='S',
                   help='longest wait for one iteration [s] (default 600)')
    p.add_argument('--grace', type=_positive, default=5.0, metavar='S',
                   help='on stop, wait this long after SIGINT before SIGKILL [s] (default 5)')
    p.add_argument('--log-dir', type=Path, default=None,
                   help='also write each node\'s output to DIR/<node>.log')
    p.add_argument('--nodes', default=None, metavar='LIST',
                   help='start only these nodes here (comma-separated, of fan_output, force_sensor, '
                        'mocap_relay, field_estimator, coordinator; sim_tunnel comes with --sim): '
                        'the graph split over hosts, each running `up --nodes ...` in the same '
                        'ROS domain (and namespace)')
    p.add_argument('--live', action='store_true',
                   help='also start live_view: the field (PointCloud2), the fans and the sweep path '
                        '(MarkerArray) on wind_shaper/live/* for RViz2 (config/rviz/wind_shaper.rviz)')
    p.add_argument('--foxglove', type=int, nargs='?', const=8765, default=None, metavar='PORT',
                   help='also serve the live view to the Foxglove app: ws://127.0.0.1:PORT (default '
                        '8765; implies --live; config/foxglove_layout.json arranges the panels)')
    p.set_defaults(func=_cmd_up)


def _nodes(listed: str | None, sim: bool, names) -> list[str]:
    """The nodes `up` starts here: all of the graph's, or the listed ones (ValueError names an
    unknown one); sim_tunnel first with --sim."""
    chosen = list(names.GRAPH_NODES)
    if listed is not None:
        wanted = [n.strip() for n in listed.split(',') if n.strip()]
        unknown = [n for n in wanted if n not in names.GRAPH_NODES]
        if unknown or not wanted:
            raise ValueError(f'--nodes: unknown node(s) {unknown or listed!r}; choose among '
                             f'{", ".join(names.GRAPH_NODES)} (sim_tunnel comes with --sim)')
        chosen = [n for n in names.GRAPH_NODES if n in wanted]
    return ([names.SIM_TUNNEL] if sim else []) + chosen


# ---------------------------------------------------------------------------------- ROS side
class _GraphClient:
    """The supervisor's own ROS participant: sees the graph, calls the iteration service."""

    def __init__(self, env: dict, namespace: str = '/'):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self._rclpy = rclpy
        self.context = rclpy.Context()
        domain = env.get('ROS_DOMAIN_ID')
        kwargs = {'domain_id': int(domain)} if domain and domain.isdigit() else {}
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO, **kwargs)
        self.namespace = namespace
        self.node = rclpy.create_node('wind_shaper_up', context=self.context, namespace=namespace)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        #: node -> (client, pending call or None, when it was sent, when it last answered)
        self._probes: dict = {}

    #: a node is asked again when its last probe call is this old without an answer [s]
    PROBE_EVERY_S = 3.0

    def answers(self, nodes) -> dict:
        """The supervisor's probe of deafness: each node in ``nodes`` is asked for none of its
        parameters (its parameter service, which every rclpy node serves from its executor)
        every ``PROBE_EVERY_S`` s; returns {node: time.monotonic() of its last answer}. A call
        must cross from this process to the node's, as the coordinator's calls do."""
        from rcl_interfaces.srv import GetParameters
        now = time.monotonic()
        probes = self._probes
        for name in nodes:
            client, future, sent, last = probes.get(name, (None, None, 0.0, None))
            if client is None:
                service = f'{self.namespace.rstrip("/")}/{name}/get_parameters'
                client = self.node.create_client(GetParameters, service)
            if future is not None and future.done():
                if not future.cancelled() and future.exception() is None:
                    last = now
                future = None
            if (future is None or now - sent >= self.PROBE_EVERY_S) and client.service_is_ready():
                # (a call sent before the service is matched would be lost, not late)
                if future is not None:      # unanswered: ask again (a restarted node is new)
                    client.remove_pending_request(future)
                future, sent = client.call_async(GetParameters.Request(names=[])), now
            probes[name] = (client, future, sent, last)
        for _ in range(2 * len(nodes)):     # take the answers that have arrived
            self.executor.spin_once(timeout_sec=0.0)
        return {n: probes[n][3] for n in nodes if probes[n][3] is not None}

    def visible(self) -> list[str]:
        """The nodes in the graph's namespace (another tunnel's nodes of the same names in the
        same domain do not count)."""
        return [name for name, ns in self.node.get_node_names_and_namespaces()
                if ns == self.namespace]

    def sim_ready(self) -> list[str]:
        """['sim_tunnel'] once its sweep service is up (created after its sockets are open)."""
        from ..ros import names
        services = {name for name, _types in self.node.get_service_names_and_types()}
        return [names.SIM_TUNNEL] if names.resolve(names.SWEEP, self.namespace) in services else []

    def run_iteration(self, target: str, timeout_s: float, keep_going, during):
        """Call run_iteration once; ``keep_going()`` False or ``during()`` raising ends the
        wait. Returns the response, or None when stopped."""
        from wind_shaper_msgs.srv import RunIteration

        from ..core.errors import WindShaperError
        from ..ros import names
        client = self.node.create_client(RunIteration, names.RUN_ITERATION)
        try:
            deadline = time.monotonic() + 30.0
            while not client.wait_for_service(timeout_sec=0.2):
                during()
                if not keep_going():
                    return None
                if time.monotonic() > deadline:
                    raise WindShaperError(f'{names.resolve(names.RUN_ITERATION, self.namespace)} is '
                                          f'not available after 30 s: '
                                          f'is the coordinator running?')
            future = client.call_async(RunIteration.Request(target=target))
            deadline = time.monotonic() + timeout_s
            while not future.done():
                self.executor.spin_once(timeout_sec=0.1)
                during()
                if not keep_going():
                    future.cancel()
                    return None
                if time.monotonic() > deadline:
                    future.cancel()
                    raise WindShaperError(f'no answer from {names.resolve(names.RUN_ITERATION, self.namespace)} within '
                                          f'{timeout_s:g} s (--iteration-timeout)')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.context.try_shutdown()


# ---------------------------------------------------------------------------------- the command
def _overrides(args) -> dict:
    out: dict = {}
    for node, name, value in args.settings:
        out.setdefault(node, {})[name] = value
    if args.run_name:
        out.setdefault('coordinator', {})[RUN_NAME_PARAM] = args.run_name
    if args.foxglove is not None:
        out.setdefault('live_view', {}).setdefault('foxglove_port', args.foxglove)
    return out


def _hint(env: dict, user_env: dict) -> str:
    """What to type in a second terminal, with the ROS settings it must share with this one."""
    added = ' '.join(f'{k}={env[k]}' for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',)
                     if env.get(k) and not user_env.get(k))
    prefix = added + ' ' if added else ''
    domain = (f' (same ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]})' if env.get('ROS_DOMAIN_ID') else '')
    ns = env.get('WIND_SHAPER_NAMESPACE', '')
    option = f'--namespace {ns} ' if ns not in ('', '/') else ''
    return (f'In a second terminal{domain}:\n'
            f'    {prefix}wind-shaper {option}iterate --target parabolic\n'
            f'    {prefix}wind-shaper {option}status\n'
            f'Ctrl-C here stops every node.')


def _cmd_up(args) -> int:
    from ..core.config import default_config_dir
    from ..core.errors import WindShaperError
    from ..ros import names
    from ..supervisor import (GraphError, NodeGaveUp, RestartPolicy, Stopped, StopSignals,
                              Supervisor, graph_env, plan_graph)
    if (args.iterations is None) != (args.target is None):
        print('wind-shaper up: --iterations and --target go together', file=sys.stderr)
        return 2
    if args.iterations is not None and args.iterations < 1:
        print('wind-shaper up: --iterations must be >= 1', file=sys.stderr)
        return 2
    shipped = default_config_dir()
    config_dir = (args.config or shipped).resolve()
    if not (config_dir / 'tunnel.yaml').is_file():
        print(f'wind-shaper up: {config_dir} has no tunnel.yaml: give the config folder with '
              f'--config', file=sys.stderr)
        return 2
    namespace = names.namespace_from_env()
    try:
        nodes = _nodes(args.nodes, args.sim, names)
    except ValueError as exc:
        print(f'wind-shaper up: {exc}', file=sys.stderr)
        return 2
    if args.live or args.foxglove is not None:
        nodes.append(names.LIVE_VIEW)
    if args.iterations is not None and names.COORDINATOR not in nodes:
        print('wind-shaper up: --iterations needs the coordinator on this host: add it to --nodes',
              file=sys.stderr)
        return 2
    specs = plan_graph(nodes, config_dir, fallback_dir=shipped, overrides=_overrides(args),
                       namespace=namespace)
    user_env = dict(os.environ)
    env = graph_env()
    os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',) if k in env})
    if args.hang_after < 0:
        print(f'wind-shaper up: --hang-after must be 0 (never) or a number of seconds, not '
              f'{args.hang_after:g}', file=sys.stderr)
        return 2
    if args.deaf_after < 0:
        print(f'wind-shaper up: --deaf-after must be 0 (never) or a number of seconds, not '
              f'{args.deaf_after:g}', file=sys.stderr)
        return 2
    policy = RestartPolicy(enabled=not args.no_restart, max_restarts=max(0, args.max_restarts),
                           hang_after_s=args.hang_after if not args.no_restart else 0.0,
                           deaf_after_s=args.deaf_after if not args.no_restart else 0.0)
    sup = Supervisor(specs, env=env, policy=policy, log_dir=args.log_dir, grace_s=args.grace)
    code = 0
    client = None
    with StopSignals() as stop:
        try:
            sup.say(f'wind-shaper up: starting {", ".join(nodes)} (config {config_dir}'
                    f'{", ROS_DOMAIN_ID " + env["ROS_DOMAIN_ID"] if env.get("ROS_DOMAIN_ID") else ""}'
                    f'{", namespace " + namespace if namespace != "/" else ""})')
            t0 = time.monotonic()
            client = _GraphClient(env, namespace)
            if args.sim:   # the rig first: the drivers then find its sockets open
                sup.start([names.SIM_TUNNEL])
                sup.wait_visible(client.sim_ready, args.startup_timeout, names=[names.SIM_TUNNEL],
                                 should_stop=stop)
            sup.start()
            sup.wait_visible(client.visible, max(1.0, args.startup_timeout - (time.monotonic() - t0)),
                             should_stop=stop)
            took = time.monotonic() - t0
            sup.watch_answers(client.answers)
            pids = ', '.join(f'{n} {pid}' for n, pid in sup.pids().items())
            sup.say(f'wind-shaper up: all {len(nodes)} nodes are up in {took:.1f} s (pids: {pids}).')
            if args.iterations is None:
                sup.say(_hint(env, user_env))
                sup.supervise(stop)
            else:
                code = _iterate(args, sup, client, stop)
        except (GraphError, NodeGaveUp, WindShaperError) as exc:
            sup.say(f'wind-shaper up: error: {exc}')
            code = 1
        except (KeyboardInterrupt, Stopped):
            pass
        finally:
            if stop():
                sup.say('wind-shaper up: stopping every node')
            if client is not None:
                client.close()
            codes = sup.shutdown()
            left = sup.pids()
            sup.say(f'wind-shaper up: stopped ({_codes_text(codes)})'
                    + (f'; STILL RUNNING: {left}' if left else ''))
    return code


def _codes_text(codes: dict) -> str:
    """{node: exit code} as "node: 0, other: SIGKILL" (nodes never started left out)."""
    import signal
    parts = []
    for name, code in codes.items():
        if code is None:
            continue
        text = str(code)
        if code < 0:
            try:
                text = signal.Signals(-code).name
            except ValueError:
                pass
        parts.append(f'{name}: {text}')
    return ', '.join(parts) or 'no node was running'


def _iterate(args, sup, client, stop) -> int:
    """Run --iterations through the graph, then write the report. Returns the exit code."""
    from ..core.errors import WindShaperError
    responses = []
    for i in range(args.iterations):
        sup.say(f'wind-shaper up: iteration {i + 1} of {args.iterations} (target {args.target})')
        response = client.run_iteration(args.target if i == 0 else '', args.iteration_timeout,
                                        keep_going=lambda: not stop(), during=sup.poll)
        if response is None:
            sup.say('wind-shaper up: interrupted; the run folder keeps the completed iterations')
            return 0
        if not response.success:
            sup.say(f'wind-shaper up: iteration failed: {response.message}')
            return 1
        responses.append(response)
        sup.say(_format_result(response))
    run_folder = _run_root(responses[-1].run_folder)
    if run_folder is None:
        sup.say(f'wind-shaper up: no run folder found at {responses[-1].run_folder!r} (the '
                f'coordinator\'s answer): no report written')
        return 1
    try:
        out = write_run_report(run_folder, args.report or run_folder / 'report',
                               config_dir=args.config)
    except WindShaperError as exc:
        sup.say(f'wind-shaper up: report not written: {exc}')
        return 1
    used = json.loads((out / 'run.json').read_text()).get('tunnel_time_s', {})
    if used:
        sup.say(f'wind-shaper up: tunnel time {used["plate_total_s"]:.0f} s of sweeping + '
                f'{used["settle_total_s"]:.0f} s of commanding and settling over {len(responses)} '
                f'iteration(s)')
    sup.say(f'wind-shaper up: run folder {run_folder}\nwind-shaper up: report {out}/ '
            f'(run.json, field_maps.png, error.png, pwm.png)')
    return 0


def _format_result(response) -> str:
    """The iteration's answer as `wind-shaper iterate` prints it (its formatter when present)."""
    try:
        from .service import format_result
    except ImportError:
        return (f'k={response.iteration} RMSE {response.rmse_before:.4f} N -> predicted '
                f'{response.rmse_predicted_after:.4f} N; {response.message}')
    return format_result(response)


def _run_root(reported: str) -> Path | None:
    """The run folder (holding run.yaml) that ``reported`` (the coordinator's run_folder: the
    run folder or an iteration's folder in it; relative paths are from the coordinator's working
    directory, which is ours) is or lies in."""
    if not reported:
        return None
    path = Path(reported).resolve()
    for folder in (path, *path.parents):
        if (folder / 'run.yaml').is_file():
            return folder
    return None


def write_run_report(run_folder: Path, out: Path, config_dir=None) -> Path:
    """The report folder (``wind_shaper.report.run_report``) of a coordinator run folder."""
    from ..app import Setup
    from ..storage import RunStore
    from ..report.run_report import write_report
    run_folder = Path(run_folder)
    store = RunStore.open(run_folder.parent, run_folder.name)
    records = store.load_history()
    if not records:
        from ..core.errors import WindShaperError
        raise WindShaperError(f'{run_folder} has no completed iteration yet')
    setup = Setup.load(config_dir)
    # tunnel time as the coordinator stamped it (re-sweeps included), per iteration and in total
    plate = [float(r.info.get('plate_s', r.plate_s)) for r in records]
    settle = [float(r.info.get('settle_s', 0.0)) for r in records]
    meta = {'run_folder': str(run_folder), 'target_spec': store.info.target,
            'created_at': store.info.created_at, 'config': store.info.config,
            'source': 'wind-shaper up (node graph)',
            'tunnel_time_s': {'plate_s': plate, 'settle_s': settle, 'plate_total_s': sum(plate),
                              'settle_total_s': sum(settle), 'total_s': sum(plate) + sum(settle)}}
    return write_report(out, records, setup.geometry, meta, u_max=setup.shaping.u_max)
