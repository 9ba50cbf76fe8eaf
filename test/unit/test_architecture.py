"""The package's layers, read from its own imports: no circle, nothing imports upward, the pure
layers never import ROS, and nothing uses the old ``wind_shaper.core.*`` paths."""
import ast
import re
import warnings
from pathlib import Path

import pytest

import wind_shaper
from wind_shaper.core.moved import MOVED

PACKAGE_DIR = Path(wind_shaper.__file__).parent

#: Each top-level part of wind_shaper and its layer: a module may import only from its own part
#: or from a part of a lower layer (two parts on one layer do not import each other).
LAYERS = {
    'core': 0,
    'protocols': 1, 'model': 1, 'estimation': 1, 'experiment': 1,
    'control': 2,
    'storage': 3, 'sim': 3, 'io': 3, 'report': 3, 'ros': 3, 'supervisor': 3,
    'bag': 4,
    'workbench': 5, 'coordination': 5, 'app': 5,
    'nodes': 6, 'cli': 6,
}
#: Parts that must run without ROS (the nodes and the CLI translate between them and ROS).
PURE = {'core', 'experiment', 'protocols', 'model', 'estimation', 'control', 'storage', 'sim', 'io', 'report',
        'workbench', 'coordination', 'app'}
ROS_MODULES = ('rclpy', 'wind_shaper_msgs', 'std_msgs', 'geometry_msgs', 'sensor_msgs',
               'std_srvs', 'diagnostic_msgs', 'visualization_msgs', 'builtin_interfaces')


def module_name(path: Path) -> str:
    parts = ('wind_shaper',) + path.relative_to(PACKAGE_DIR).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def modules() -> dict:
    return {module_name(p): p for p in sorted(PACKAGE_DIR.rglob('*.py'))}


MODULES = modules()


def imports_of(name: str, path: Path) -> list[str]:
    """Every module ``name`` imports (also inside functions), resolved to absolute names; a
    ``from package import x`` counts x when x is a module, and the package itself only when
    some name comes from its ``__init__``."""
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')[:len(package.split('.')) - node.level + 1]
                source = '.'.join(base + ([node.module] if node.module else []))
            else:
                source = node.module
            submodules = [f'{source}.{a.name}' for a in node.names if f'{source}.{a.name}' in MODULES]
            if len(submodules) < len(node.names):  # some name comes from the module itself
                out.append(source)
            out += submodules
    return out


def part(name: str) -> str:
    return name.split('.')[1] if name.count('.') else ''


GRAPH = {name: [m for m in imports_of(name, path) if m in MODULES and m != name]
         for name, path in MODULES.items()}


def test_every_part_has_a_layer():
    parts = {part(n) for n in MODULES} - {''}
    assert parts <= set(LAYERS), f'give these parts a layer: {sorted(parts - set(LAYERS))}'


def test_no_import_circle():
    # Tarjan's strongly connected components over the module graph
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in GRAPH[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in GRAPH:
        if v not in index:
            visit(v)
    assert not circles, f'modules that import each other: {circles}'


def test_nothing_imports_upward_or_sideways():
    wrong = [f'{name} imports {target}' for name, targets in GRAPH.items() for target in targets
             if part(name) and part(target) and part(name) != part(target)
             and LAYERS[part(target)] >= LAYERS[part(name)]]
    assert not wrong, 'imports against the layers (lower or same-layer parts must not import ' \
                      'these):\n' + '\n'.join(wrong)


def test_the_pure_parts_never_import_ros():
    wrong = [f'{name} imports {m}' for name, path in MODULES.items() if part(name) in PURE
             for m in imports_of(name, path) if m.split('.')[0] in ROS_MODULES]
    assert not wrong, '\n'.join(wrong)


def test_no_module_uses_an_old_core_path():
    wrong = [f'{name} imports {m}' for name, path in MODULES.items()
             for m in imports_of(name, path) if m in MOVED]
    assert not wrong, '\n'.join(wrong)


@pytest.mark.parametrize('old', sorted(MOVED))
def test_an_old_import_path_still_works_and_names_the_new_one(old):
    import importlib
    import sys
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        module = importlib.import_module(old)
    assert module is importlib.import_module(MOVED[old])
    assert any(MOVED[old] in str(w.message) and issubclass(w.category, DeprecationWarning)
               for w in caught)


def test_a_plugin_written_against_the_old_api_still_defines_a_term():
    import sys
    for old in ('wind_shaper.core.model', 'wind_shaper.core.effects'):
        sys.modules.pop(old, None)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)
        from wind_shaper.core.effects import FanGain, Wrapper
        from wind_shaper.core.model import Hyper, Term, register_term
    from wind_shaper.model import FanGain as new_fan_gain
    assert FanGain is new_fan_gain and issubclass(Wrapper, Term)
    assert callable(register_term) and Hyper is not None


#: a logging call whose severity a condition picks on one line: ``(log.warning if c else log.info)(m)``
_SEVERITY_BY_CONDITION = re.compile(r'\(\s*[\w.()]*\.(?:debug|info|warning|warn|error|fatal)\s+if\b')


def test_no_logging_line_picks_its_severity_by_a_condition():
    """rclpy keys each logging call by its line and raises when one line logs at a second
    severity: a node that logged a note as information and later one as a warning from the
    same line crashed (at start, or in a service's answer). ``ros.log.log_note`` gives each
    severity its own line."""
    found = [f'{path.relative_to(PACKAGE_DIR.parent)}:{n}'
             for path in sorted(PACKAGE_DIR.rglob('*.py'))
             for n, line in enumerate(path.read_text().splitlines(), 1)
             if _SEVERITY_BY_CONDITION.search(line)]
    assert not found, f'use wind_shaper.ros.log.log_note instead: {found}'


def test_the_nodes_that_relay_messages_start_without_scipy():
    """fan_output, force_sensor and mocap_relay never fit a GP or solve a model: importing
    SciPy with them cost each start 0.4-0.6 s of CPU (bench/node_start.py), paid again at
    every restart the supervisor makes. A module-level SciPy import on their path fails this."""
    import subprocess
    import sys
    code = ('import sys\n'
            'import wind_shaper.nodes.fan_output, wind_shaper.nodes.force_sensor, '
            'wind_shaper.nodes.mocap_relay\n'
            'print(sorted({m.split(".")[0] for m in sys.modules} & {"scipy", "sklearn"}))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == '[]', out.stdout
