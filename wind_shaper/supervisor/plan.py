"""The graph as a plan (no rclpy): ``plan_graph`` turns a config folder into one ``NodeSpec``
per node, ``python -m wind_shaper.nodes.<node> --ros-args --params-file <config>/<node>.yaml -p
key:=value ...``, sim_tunnel first when simulating; ``graph_env`` is the children's environment.
The processes themselves are ``processes.Supervisor``'s.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import yaml

from ..core.errors import WindShaperError
from ..core.safe_yaml import read_yaml_file


class GraphError(WindShaperError):
    """The graph could not be brought up (a node did not start or did not appear)."""


@dataclass(frozen=True)
class NodeSpec:
    """One node process: name (= ROS node name), the full command line, and where its
    parameters come from (for messages)."""

    name: str
    argv: tuple[str, ...]
    params_file: Path | None = None
    note: str = ''


def format_value(value) -> str:
    """A parameter value as ROS's ``-p name:=value`` expects it (YAML flow syntax)."""
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(format_value(v) if not isinstance(v, str) else repr(v)
                               for v in value) + ']'
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()


def node_command(node: str, params_file: Path | None = None,
                 overrides: Mapping[str, object] | None = None,
                 python: str = sys.executable, namespace: str = '/') -> list[str]:
    """``python -m wind_shaper.nodes.<node> --ros-args [-r __ns:=NS] [--params-file F]
    [-p k:=v ...]``."""
    argv = [python, '-m', f'wind_shaper.nodes.{node}', '--ros-args']
    if namespace not in ('', '/'):
        argv += ['-r', f'__ns:={namespace}']
    if params_file is not None:
        argv += ['--params-file', str(params_file)]
    for key, value in (overrides or {}).items():
        argv += ['-p', f'{key}:={format_value(value)}']
    return argv


def _coerce(value, like):
    """``value`` as the type of the params file's ``like`` where ROS would refuse it otherwise:
    an integer given for a float parameter (``sweep_duration_s=3``) becomes 3.0."""
    if isinstance(like, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(like, list) and isinstance(value, list) and like and all(
            isinstance(v, float) for v in like):
        return [_coerce(v, 0.0) for v in value]
    return value


def _declared(params_file: Path, node: str) -> dict[str, object]:
    try:
        doc = read_yaml_file(params_file) or {}
        return _flat(dict((doc.get(node) or {}).get('ros__parameters') or {}))
    except (OSError, yaml.YAMLError, AttributeError) as exc:
        raise GraphError(f'{params_file} is not a readable node parameter file ({exc}); it must '
                         f'hold "{node}: {{ros__parameters: {{...}}}}"') from None


def _flat(params: Mapping, prefix: str = '') -> dict[str, object]:
    """Nested parameter sections as ROS names them: ``{limits: {fans: 64}}`` ->
    ``{'limits.fans': 64}``."""
    out: dict[str, object] = {}
    for key, value in params.items():
        if isinstance(value, Mapping):
            out.update(_flat(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def plan_graph(nodes: Sequence[str], config_dir: Path, *, fallback_dir: Path | None = None,
               overrides: Mapping[str, Mapping[str, object]] | None = None,
               python: str = sys.executable, namespace: str = '/') -> list[NodeSpec]:
    """One ``NodeSpec`` per node, in order. Parameters come from ``config_dir/<node>.yaml``, or
    from ``fallback_dir/<node>.yaml`` (the shipped one) when the folder has none. Nodes whose
    file declares ``config_dir`` get it pointed at ``config_dir``; ``overrides`` {node: {name:
    value}} are added last (they win), typed like the file's value (an integer for a float
    parameter becomes a float). An override of an undeclared parameter is refused. namespace:
    the ROS namespace every node starts in (its relative names resolve under it)."""
    config_dir = Path(config_dir).resolve()
    overrides = {k: dict(v) for k, v in (overrides or {}).items()}
    unknown = set(overrides) - set(nodes)
    if unknown:
        raise GraphError(f'parameter overrides for nodes not in the graph: {sorted(unknown)}; '
                         f'nodes are {", ".join(nodes)}')
    specs = []
    for node in nodes:
        path, note = config_dir / f'{node}.yaml', ''
        if not path.is_file() and fallback_dir is not None:
            shipped = Path(fallback_dir) / f'{node}.yaml'
            if shipped.is_file():
                path, note = shipped, f'{config_dir} has no {node}.yaml: using the shipped {shipped}'
        if not path.is_file():
            raise GraphError(f'no parameter file for node {node}: put a {node}.yaml in '
                             f'{config_dir}')
        declared = _declared(path, node)
        params: dict[str, object] = {}
        if 'config_dir' in declared:
            params['config_dir'] = str(config_dir)
        for key, value in overrides.get(node, {}).items():
            if key not in declared:
                raise GraphError(f'{node} has no parameter {key!r} (see {path}); its parameters '
                                 f'are {", ".join(sorted(declared))}')
            params[key] = _coerce(value, declared[key])
        specs.append(NodeSpec(node, tuple(node_command(node, path, params, python, namespace)),
                              path, note))
    return specs


def graph_env(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The children's environment: ``base`` (default os.environ) with unbuffered Python output
    and ROS discovery kept on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) unless the
    user chose a discovery setting (ROS_AUTOMATIC_DISCOVERY_RANGE, ROS_LOCALHOST_ONLY or
    ROS_STATIC_PEERS), and Fast DDS on UDP only (FASTDDS_BUILTIN_TRANSPORTS=UDPv4) unless the
    user chose its transports.

    Why UDP: the supervisor restarts a node killed or hung in the middle of a stream, and Fast
    DDS's shared-memory transport does not always recover from a participant killed while it
    used a port (a relay restarted on it once blocked forever publishing, in the transport's
    port code; eProsima's Fast-DDS tracker has reports of restarted subscribers that receive
    nothing, e.g. GitHub 5053 and 5469). Loopback UDP carries the graph's few hundred small
    messages a second easily."""
    env = dict(os.environ if base is None else base)
    env['PYTHONUNBUFFERED'] = '1'
    if not any(env.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOCALHOST_ONLY',
                                    'ROS_STATIC_PEERS')):
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not env.get('FASTDDS_BUILTIN_TRANSPORTS'):
        env['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
    return env
