"""Plugins: a model file naming a term kind of the user's own loads wherever the plugin is named,
by --plugin or by the WIND_SHAPER_PLUGINS environment variable (which the nodes of `wind-shaper
up` inherit); without it the error says how to fix it."""
import os
import subprocess
import sys
import textwrap
import uuid

import pytest
import yaml

from wind_shaper.model import plugins
from wind_shaper.core.errors import ConfigError, ModelFileError
from wind_shaper.model import TERMS, term_from_dict

PLUGIN = '''
import numpy as np
from wind_shaper.model import Hyper, Term, register_term

@register_term
class Bump(Term):
    """Phi = height * exp(-|z|^2 / 0.1^2) [N], whatever the commands."""
    kind = {kind!r}
    hypers = (Hyper('height', 1, (0.0, 5.0)),)

    def __init__(self, fans, height=0.0, fixed=()):
        self.fans = fans
        self.height = float(height)
        self._init_hypers(fixed)
        self._check_bounds()

    def _value_and_grad(self, U, Z, jacobian):
        G = np.exp(-(Z[:, 0] ** 2 + Z[:, 1] ** 2) / 0.01)
        return self.height * G, (np.zeros_like(U) if jacobian else None)

FAMILIES = ['a family']
'''


def write_plugin(folder, name='bump'):
    """A plugin file registering a term kind no other test knows; returns (path, kind)."""
    kind = f'bump_{uuid.uuid4().hex[:8]}'
    path = folder / f'{name}.py'
    path.write_text(PLUGIN.format(kind=kind))
    return path, kind


def test_an_unknown_kind_says_how_to_load_it(rig):
    with pytest.raises(ModelFileError) as exc:
        term_from_dict({'kind': 'straightener_gap_nowhere'}, rig.fans)
    assert "unknown model term kind 'straightener_gap_nowhere'" in str(exc.value)
    assert '--plugin FILE or WIND_SHAPER_PLUGINS' in str(exc.value)


def test_the_environment_variable_is_honoured_when_a_kind_is_unknown(rig, tmp_path, monkeypatch):
    path, kind = write_plugin(tmp_path)
    other, _ = write_plugin(tmp_path, 'other')
    assert kind not in TERMS
    monkeypatch.setenv(plugins.ENV_VAR, os.pathsep.join([str(other), str(path)]))
    term = term_from_dict({'kind': kind, 'height': 0.5}, rig.fans)
    assert term.kind == kind and term.height == 0.5


def test_a_missing_plugin_of_the_environment_is_named(rig, tmp_path, monkeypatch):
    monkeypatch.setenv(plugins.ENV_VAR, str(tmp_path / 'gone.py'))
    with pytest.raises(ModelFileError, match='gone.py.*WIND_SHAPER_PLUGINS'):
        term_from_dict({'kind': 'bump_never_registered'}, rig.fans)


def test_each_plugin_is_imported_once_and_offers_its_families(tmp_path, monkeypatch):
    path, _ = write_plugin(tmp_path)
    monkeypatch.setenv(plugins.ENV_VAR, str(path))
    mods = plugins.load_plugins([str(path)])
    assert len(mods) == 1 and plugins.load_plugins([]) == mods
    assert plugins.plugin_families(mods) == ['a family']


def test_a_broken_plugin_is_refused_with_its_name(tmp_path):
    bad = tmp_path / 'broken_plugin.py'
    bad.write_text('raise RuntimeError("no such hardware")\n')
    with pytest.raises(ConfigError, match='broken_plugin.py.*no such hardware'):
        plugins.load_plugin(bad)
    with pytest.raises(ConfigError, match='does not exist'):
        plugins.load_plugin(tmp_path / 'missing.py')


def test_a_fresh_process_reads_the_model_file_with_the_environment_variable(tmp_path):
    """What a node started by `wind-shaper up` does: load_model in a new interpreter whose
    environment names the plugin."""
    path, kind = write_plugin(tmp_path)
    model = tmp_path / 'model.yaml'
    from wind_shaper.app import Setup
    base = yaml.safe_load(Setup.load().model_path.read_text())
    base['model'] = {'kind': 'sum', 'terms': [base['model'], {'kind': kind, 'height': 0.3}]}
    model.write_text(yaml.safe_dump(base))
    code = textwrap.dedent(f'''
        from wind_shaper.app import Setup
        print(type(Setup.load().load_model({str(model)!r}).k2).__name__)
    ''')
    env = {k: v for k, v in os.environ.items() if k != plugins.ENV_VAR}
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode != 0 and '--plugin FILE or WIND_SHAPER_PLUGINS' in done.stderr
    env[plugins.ENV_VAR] = str(path)
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'Bump'
