"""What the fuzz tier tries: every service request the coordinator takes, checked the way its
node checks it, and every file wind_shaper reads, each as a hypothesis strategy and a target.

A target gets one example and returns 'ok' (a result) or 'refused' (a WindShaperError or a
yaml.YAMLError saying what was wrong, in a short message); any other exception is a crash and
fails the run. test/fuzz runs a few examples of each in CI; bench/fuzz.py runs many and prints
what it tried. Hostile building blocks: anchors and aliases, deep nesting, huge and non-finite
numbers, long strings, control characters and binary, each spliced into a valid document.
"""
from __future__ import annotations

import atexit
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import yaml
from hypothesis import strategies as st

from wind_shaper.app import Setup
from wind_shaper.coordination import Experiment
from wind_shaper.coordination.requests import (check_collect_request, check_hold_request,
                                               check_model_request, check_target_request)
from wind_shaper.core.config import read_yaml
from wind_shaper.core.errors import WindShaperError
from wind_shaper.core.limits import DEFAULT_LIMITS
from wind_shaper.experiment import check_design, make_design
from wind_shaper.model.modelfile import model_from_text
from wind_shaper.workbench.data import load_sweeps

#: The longest refusal message a target accepts [characters].
MAX_MESSAGE = 2000

_SETUP = None
_BASE: dict[str, object] = {}


def setup() -> Setup:
    global _SETUP
    if _SETUP is None:
        _SETUP = Setup.load()
    return _SETUP


# -- building blocks ---------------------------------------------------------------------------------
HOSTILE_SNIPPETS = [
    '&a [1, 2]', '*a', '!!python/object:os.system {}', '!!binary AAAA', '[' * 200 + ']' * 200,
    '{' * 60 + '}' * 60, '9' * 5000, '1e400', '-.inf', '.nan', '0x' + 'f' * 40, '2001-13-45',
    '"\\ud800"', '~', '[]', '{}', "''", 'yes', '- - - -', '? [a]: b', '!!set {a, b}',
    '!!omap [a: 1]', '\t', '%YAML 1.1\n---', '--- !!str', '...', '@', '`', '|\n  x', '>-\n  x',
]


def hostile_text(max_size: int = 400) -> st.SearchStrategy[str]:
    """Short texts: hostile YAML snippets, random printable and control characters."""
    return st.one_of(st.sampled_from(HOSTILE_SNIPPETS),
                     st.text(max_size=max_size),
                     st.text(alphabet='[]{}:,-&*!|>"\'# \n\tab01.e', max_size=max_size))


def yaml_values() -> st.SearchStrategy:
    """Plain YAML values, nested a few levels (numbers of every kind, strings, lists, maps)."""
    leaves = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(),
                       st.text(max_size=30))
    return st.recursive(leaves, lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=10), inner, max_size=5)),
        max_leaves=20)


@st.composite
def mutated(draw, base: str) -> str:
    """``base`` with a few edits: a value replaced by a hostile snippet or random YAML, a cut,
    an insertion of random text, or a duplicated stretch."""
    text = base
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(['replace', 'cut', 'insert', 'repeat', 'value']))
        if not text:
            text = draw(hostile_text())
            continue
        i = draw(st.integers(0, len(text) - 1))
        j = draw(st.integers(i, min(len(text), i + 80)))
        if kind == 'replace':
            text = text[:i] + draw(hostile_text(80)) + text[j:]
        elif kind == 'cut':
            text = text[:i] + text[j:]
        elif kind == 'insert':
            text = text[:i] + draw(st.text(max_size=40)) + text[i:]
        elif kind == 'repeat':
            text = text[:j] + text[i:j] * draw(st.integers(1, 50)) + text[j:]
        else:   # a value of a `key: value` line replaced by random YAML
            lines = text.split('\n')
            n = draw(st.integers(0, len(lines) - 1))
            key, sep, _ = lines[n].partition(':')
            if sep:
                dumped = yaml.safe_dump(draw(yaml_values()), default_flow_style=True).strip()
                lines[n] = f'{key}: {dumped}'
            text = '\n'.join(lines)
    return text


def classify(call, *args, **kwargs) -> str:
    """'ok' or 'refused' (a short WindShaperError or yaml.YAMLError); anything else raises."""
    try:
        call(*args, **kwargs)
    except (WindShaperError, yaml.YAMLError) as exc:
        message = str(exc)
        assert len(message) < MAX_MESSAGE, f'a refusal of {len(message)} characters: {message[:300]}'
        return 'refused'
    return 'ok'


# -- valid documents to mutate -------------------------------------------------------------------------
def model_text() -> str:
    return (setup().config_dir / 'model.yaml').read_text()


def read_yaml_text(text: str) -> dict:
    return yaml.safe_load(text)


def design_csv() -> str:
    fans = setup().geometry.fans.names
    rows = ['label,' + ','.join(fans)]
    rows += [f'sweep {i},' + ','.join('0.5' if e else '0' for e in setup().geometry.fans.enabled)
             for i in range(3)]
    return '\n'.join(rows) + '\n'


def design_yaml() -> str:
    fans = setup().geometry.fans
    sweeps = [{'label': f'sweep {i}', 'pwm': {n: (0.5 if e else 0.0) for n, e in
                                                zip(fans.names, fans.enabled)}} for i in range(3)]
    return yaml.safe_dump({'design': sweeps}, sort_keys=False)


def _base(name: str, make) -> object:
    if name not in _BASE:
        _BASE[name] = make()
    return _BASE[name]


def _scratch(prefix: str) -> Path:
    """A temporary folder removed when the test process exits (the bases live that long)."""
    root = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    return root


def experiment_folder() -> Path:
    """A stored experiment (3 rows, one swept) to copy and damage."""
    def make():
        root = _scratch('fuzz-exp-')
        s = setup()
        fans = list(s.geometry.fans.names)
        U = np.where(s.geometry.fans.enabled, 0.5, 0.0)
        exp = Experiment.open(s, root, 'exp', fans, np.tile(U, 3).tolist(), [], 'fuzz')
        sim = s.make_sim(seed=0)
        sim.apply(U)
        exp.store.write_sweep(0, sim.sweep(200), {'coverage': 1.0})
        return root / 'exp'
    return _base('experiment', make)


def bag_folder() -> Path:
    def make():
        from wind_shaper.bag.sweeps import write_sweep_bag
        root = _scratch('fuzz-bag-')
        sim = setup().make_sim(seed=0)
        sim.apply(np.where(setup().geometry.fans.enabled, 0.5, 0.0))
        return write_sweep_bag(root / 'bag', [sim.sweep(200), sim.sweep(200)],
                               fan_names=list(setup().geometry.fans.names))
    return _base('bag', make)


# -- file targets ------------------------------------------------------------------------------------
def target_model_file(text: str) -> str:
    def read():
        model = model_from_text(text, setup().geometry.fans, source='the model file')
        model.jacobian(np.full(setup().geometry.fans.n_fans, 0.5), setup().geometry.key_points[:5])
    return classify(read)


def _in_tmp(name: str, data, call) -> str:
    folder = Path(tempfile.mkdtemp(prefix='fuzz-'))
    try:
        path = folder / name
        (path.write_bytes if isinstance(data, bytes) else path.write_text)(data)
        return call(path)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def target_design_csv(text: str) -> str:
    b = setup().shaping.bounds
    return _in_tmp('design.csv', text.encode('utf-8', 'surrogatepass'),
                   lambda p: classify(make_design, str(p), setup().geometry.fans, b.u_min, b.u_max))


def target_design_yaml(text: str) -> str:
    b = setup().shaping.bounds
    return _in_tmp('design.yaml', text.encode('utf-8', 'surrogatepass'),
                   lambda p: classify(make_design, str(p), setup().geometry.fans, b.u_min, b.u_max))


def target_config_yaml(text: str) -> str:
    """A node's or the tunnel's config file, as every node reads it at start."""
    def read(path):
        def load():
            doc = read_yaml(path)
            from wind_shaper.core.geometry import TunnelGeometry
            TunnelGeometry.from_config(doc.get('tunnel', {}))
        return classify(load)
    return _in_tmp('tunnel.yaml', text.encode('utf-8', 'surrogatepass'), read)


def _damaged_folder(base: Path, edits: dict[str, bytes]) -> str:
    folder = Path(tempfile.mkdtemp(prefix='fuzz-folder-'))
    try:
        copy = folder / base.name
        shutil.copytree(base, copy)
        for rel, data in edits.items():
            path = copy / rel
            if path.exists() or rel.endswith(('.yaml', '.json')):
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_bytes(data)
        return classify(load_sweeps, copy)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def target_experiment_folder(edit: tuple[str, str | bytes]) -> str:
    which, data = edit
    if isinstance(data, str):
        data = data.encode('utf-8', 'surrogatepass')
    return _damaged_folder(experiment_folder(), {which: data})


@st.composite
def damaged_bytes(draw, base: bytes) -> bytes:
    """``base`` cut short at any point, or with a few bytes overwritten (a copy interrupted, a
    disk error): the damage binary files meet."""
    if draw(st.booleans()):
        return base[:draw(st.integers(0, max(len(base) - 1, 0)))]
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 8))):
        data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
    return bytes(data)


@st.composite
def damaged_tree(draw, doc: dict) -> str:
    """The YAML of ``doc`` with one entry, at any depth, replaced by a random YAML value (a
    mapping where a number belongs, a list where a mapping belongs, NaN, a huge integer)."""
    doc = yaml.safe_load(yaml.safe_dump(doc))
    paths, stack = [], [((), doc)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, dict):
            for key, value in node.items():
                paths.append(path + (key,))
                stack.append((path + (key,), value))
    path = draw(st.sampled_from(paths))
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = draw(st.one_of(yaml_values(), st.sampled_from(
        [float('nan'), float('inf'), 10 ** 400, 1e-12, 1e12, -1, 0, [], {}, 'x' * 300])))
    return yaml.safe_dump(doc, sort_keys=False)


def target_bag(edit: tuple[str, bytes]) -> str:
    which, data = edit
    return _damaged_folder(bag_folder(), {which: data})


# -- request targets (each field as the node checks it, then parsed as the node parses it) ------------
def target_set_model(request: tuple[str, str]) -> str:
    text, path = request
    return classify(lambda: (check_model_request(DEFAULT_LIMITS, text, path),
                             model_from_text(text, setup().geometry.fans)))


def target_run_iteration(target: str) -> str:
    s = setup()
    return classify(lambda: (check_target_request(DEFAULT_LIMITS, target),
                             s.make_target(target, model=s.load_model())))


def target_collect(request: tuple) -> str:
    name, design, fans, commands, labels = request
    root = Path(tempfile.mkdtemp(prefix='fuzz-collect-'))
    try:
        def run():
            check_collect_request(DEFAULT_LIMITS, name, design, fans, commands, labels, 22.0)
            Experiment.open(setup(), root, name, fans, commands, labels, design)
        return classify(run)
    finally:
        shutil.rmtree(root, ignore_errors=True)


def target_hold_point(request: tuple) -> str:
    fans, pwm = request
    s = setup()
    return classify(lambda: (check_hold_request(DEFAULT_LIMITS, fans, pwm),
                             check_design(list(fans), np.array([pwm], dtype=float), ['this point'],
                                          s.geometry.fans, s.shaping.bounds.u_min,
                                          s.shaping.bounds.u_max, 'hold_point')))


# -- strategies ---------------------------------------------------------------------------------------
def _fan_names() -> st.SearchStrategy[list[str]]:
    real = list(setup().geometry.fans.names)
    return st.one_of(st.just(real), st.permutations(real),
                     st.lists(st.one_of(st.sampled_from(real), st.text(max_size=300)), max_size=80))


def _commands() -> st.SearchStrategy[list[float]]:
    return st.lists(st.one_of(st.floats(), st.sampled_from([0.0, 0.3, 0.5, 0.9])), max_size=120)


def strategies() -> dict:
    """name (one of NAMES) -> (strategy, target); makes the valid documents it mutates."""
    exp_files = ['experiment.yaml', 'sweeps/s000/record.json', 'sweeps/s000/sweep.npz',
                 'design.csv']
    bag_files = ['metadata.yaml', 'bag_0.mcap']
    tunnel_text = (setup().config_dir / 'tunnel.yaml').read_text()
    return {
        'model file': (st.one_of(mutated(model_text()), hostile_text()), target_model_file),
        'design CSV': (st.one_of(mutated(design_csv()), hostile_text()), target_design_csv),
        'design YAML': (st.one_of(mutated(design_yaml()), hostile_text()), target_design_yaml),
        'config YAML': (st.one_of(mutated(tunnel_text), damaged_tree(read_yaml_text(tunnel_text)),
                                  hostile_text()), target_config_yaml),
        'experiment folder': (st.tuples(st.sampled_from(exp_files), st.one_of(
            mutated((experiment_folder() / 'experiment.yaml').read_text()),
            mutated(json.dumps({'coverage': 1.0, 'n_pairs': 200})), hostile_text())) | st.tuples(
            st.just('sweeps/s000/sweep.npz'),
            damaged_bytes((experiment_folder() / 'sweeps' / 's000' / 'sweep.npz').read_bytes())),
            target_experiment_folder),
        'bag': (st.tuples(st.sampled_from(bag_files), st.one_of(
            st.binary(max_size=2000),
            mutated((bag_folder() / 'metadata.yaml').read_text()).map(str.encode))), target_bag),
        'set_model request': (st.tuples(st.one_of(mutated(model_text()), hostile_text()),
                                        st.one_of(st.just(''), st.text(max_size=50))),
                              target_set_model),
        'run_iteration target': (st.one_of(
            st.sampled_from(['parabolic', 'uniform:2.5', 'gaussian@LM1', 'expr:x+y', 'csv:/dev/zero',
                             'csv:/etc/passwd', 'expr:' + '(' * 100 + 'x' + ')' * 100,
                             'expr:9**9**9**9', 'expr:' + 'x+' * 2000 + 'x']),
            st.builds(lambda k, rest: f'{k}:{rest}', st.sampled_from(
                ['parabolic', 'uniform', 'gaussian', 'gaussian@LM1', 'expr', 'csv']), hostile_text(200)),
            hostile_text()), target_run_iteration),
        'collect request': (st.tuples(
            st.one_of(st.just('exp'), st.text(max_size=300), st.sampled_from(['..', '/etc', 'a/b', '.'])),
            st.text(max_size=50), _fan_names(), _commands(),
            st.lists(st.text(max_size=50), max_size=10)), target_collect),
        'hold_point request': (st.tuples(_fan_names(), _commands()), target_hold_point),
    }


#: Every target, in the order ``strategies`` builds them.
NAMES = ['model file', 'design CSV', 'design YAML', 'config YAML', 'experiment folder', 'bag',
         'set_model request', 'run_iteration target', 'collect request', 'hold_point request']

__all__ = ['MAX_MESSAGE', 'NAMES', 'classify', 'setup', 'strategies']
