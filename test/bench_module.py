"""Import a bench/ script as a module in a test, leaving the process's BLAS settings as they were;
and where each script's quickest run is tested (every script has one, so none rots unseen)."""
import importlib.util
import os
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / 'bench'


def load_bench(name: str):
    """bench/<name>.py as a module; the BLAS thread settings it makes on import are undone."""
    keep = {k: os.environ.get(k) for k in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS')}
    spec = importlib.util.spec_from_file_location(f'bench_{name}', BENCH / f'{name}.py')
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
    finally:
        for k, v in keep.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return module


#: script -> its quickest arguments, run in-process by test/unit/test_bench_smoke.py (the results
#: file is added: --json in the test's folder)
QUICK = {
    'coverage': ['--effects', 'background_draft', '--sizes', '1', '--seeds', '1', '--clean', '1',
                 '--sweeps', '6', '--samples', '300', '--jobs', '1'],
    'field_std': ['--quick', '--estimator', 'long_run_span_s=0'],
    'scale': ['--quick'],
    # warm+bias: the bench's path to the tunnel's sensor bias, too
    'convergence': ['--quick', '--seeds', '1', '--iterations', '1', '--methods', 'warm+short,warm+bias',
                    '--targets', 'uniform'],
    'random_tunnels': ['--quick'],
    'clocks': ['--quick', '--jobs', '1'],
    'detection': ['--seeds', '1', '--kinds', 'clean', '--counts', '6', '--jobs', '1'],
    'diagnosis_speed': ['--quick'],
    'paper_cases': ['--seeds', '1', '--iterations', '2', '--cases', '1'],
    'suggest': ['--quick'],
    'replay_timing': ['--quick'],
    # one node process at a time, beside the node tests of the same lane
    'node_start': ['--quick'],
    # the fault table from one file's fault tests (the graph's own run in the graph tier)
    'faults': ['test/unit/protocols/test_netft_codec.py'],
}
#: script -> its quickest arguments, run by test/graph/test_graph_benches.py: these start ROS
#: processes, the node graph or network namespaces
GRAPH_QUICK = {
    'force_stream': ['--rates', '1000', '--seconds', '1.5'],
    'iteration_split': ['--iterations', '1', '--sweep', '3'],
    'kill_loop': ['--cycles', '1', '--nodes', 'mocap_relay'],
    'hosts': ['--rates', '1000', '--seconds', '1', '--iterations', '1'],
    'commissioning': ['--quick'],
}
#: script -> the test that runs it at its quickest
ELSEWHERE = {
    'fuzz': 'test/fuzz/test_fuzz.py (two targets at two examples; the coordinator run at two)',
}
