"""User plugins: Python files (or modules) that register model terms of their own, candidate
families for the diagnosis, or simulator effects.

A model file may name a term kind that only a plugin defines (``kind: straightener_gap``). Every
program that reads such a file must import the plugin first; it finds it in two places:

* ``--plugin FILE.py`` (or a module name) on the command line (``wind-shaper shape``,
  ``wind-shaper model ...``);
* the environment variable ``WIND_SHAPER_PLUGINS``: .py files (or module names) separated by
  ``os.pathsep`` (``:`` on Linux). ``wind_shaper.model.terms.term_from_dict`` imports them when
  a model file names a kind it does not know, so every process honours it, including the nodes
  started by ``wind-shaper up`` (they inherit its environment).

Each plugin is imported once per process, whichever way it was named.
"""
from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from pathlib import Path
from types import ModuleType
from typing import Iterable

from ..core.errors import ConfigError

__all__ = ['ENV_VAR', 'HOW_TO_LOAD', 'env_plugins', 'load_plugin', 'load_plugins', 'plugin_families']

#: The environment variable listing plugins (os.pathsep-separated .py files or module names).
ENV_VAR = 'WIND_SHAPER_PLUGINS'

#: How to make a term kind of your own known, for error messages.
HOW_TO_LOAD = (f'import the file that defines it with --plugin FILE or {ENV_VAR} '
               f'(.py files separated by "{os.pathsep}"; the node graph of `wind-shaper up` reads '
               f'{ENV_VAR} from the environment it was started in)')

_loaded: dict[str, ModuleType] = {}


def env_plugins(environ=None) -> list[str]:
    """The plugins named in ``WIND_SHAPER_PLUGINS`` (of ``environ``, default os.environ)."""
    text = (os.environ if environ is None else environ).get(ENV_VAR, '')
    return [p.strip() for p in text.split(os.pathsep) if p.strip()]


def load_plugin(spec, *, origin: str = '--plugin') -> ModuleType:
    """Import one plugin: a ``.py`` file or a module name (once per process). ``origin`` names
    where it was given, for the error message."""
    spec = str(spec)
    path = Path(spec).expanduser()
    if path.suffix == '.py':
        key = str(path.resolve())
        if key in _loaded:
            return _loaded[key]
        if not path.is_file():
            raise ConfigError(f'plugin {spec} ({origin}) does not exist: give the path of a .py file')
        name = f'wind_shaper_plugin_{path.stem}'
        n = 1
        while name in sys.modules:  # another file of the same name
            n += 1
            name = f'wind_shaper_plugin_{path.stem}_{n}'
        mod_spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(mod_spec)
        sys.modules[name] = module
        try:
            mod_spec.loader.exec_module(module)
        except Exception as exc:  # a broken plugin: say which and why, do not half-register it
            sys.modules.pop(name, None)
            raise ConfigError(f'plugin {spec} ({origin}) failed to import: '
                              f'{type(exc).__name__}: {exc}') from exc
    else:
        key = spec
        if key in _loaded:
            return _loaded[key]
        try:
            module = importlib.import_module(spec)
        except ImportError as exc:
            raise ConfigError(f'cannot import plugin {spec!r} ({origin}): {exc}') from None
    _loaded[key] = module
    return module


def load_plugins(specs: Iterable = (), *, env: bool = True) -> list[ModuleType]:
    """Import the plugins ``specs`` (from --plugin) and, with ``env``, those of
    ``WIND_SHAPER_PLUGINS``; return the modules (each once, in that order)."""
    out: list[ModuleType] = []
    named = [(s, '--plugin') for s in specs or ()]
    if env:
        named += [(s, ENV_VAR) for s in env_plugins()]
    for spec, origin in named:
        module = load_plugin(spec, origin=origin)
        if all(module is not m for m in out):
            out.append(module)
    return out


def plugin_families(modules: Iterable[ModuleType]) -> list:
    """The candidate families the modules offer (their module-level ``FAMILIES`` lists)."""
    return [f for m in modules for f in getattr(m, 'FAMILIES', [])]
