"""Running the node graph for ``wind-shaper up`` without ROS in this process: ``plan`` (which
processes, with which parameters and environment) and ``processes`` (start, watch, restart,
stop them; see its docstring)."""
from ..core.heartbeat import HEARTBEAT_ENV
from .plan import GraphError, NodeSpec, format_value, graph_env, node_command, plan_graph
from .processes import (CONFIG_ERROR_EXIT, NodeGaveUp, RestartPolicy, Stopped, StopSignals,
                        Supervisor)

__all__ = ['NodeSpec', 'RestartPolicy', 'Supervisor', 'GraphError', 'NodeGaveUp', 'Stopped',
           'StopSignals', 'plan_graph', 'node_command', 'graph_env', 'format_value',
           'CONFIG_ERROR_EXIT', 'HEARTBEAT_ENV']
