"""Every `wind-shaper ...` command that the code's messages or the docs tell a user to run exists
(its --help works), so does every bench/ and tools/ script the docs show (its --help works), and
`wind-shaper targets template` writes a target a run accepts."""
import importlib.util
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from wind_shaper.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
SOURCES = (sorted((ROOT / 'wind_shaper').rglob('*.py')) + [ROOT / 'README.md']
           + sorted((ROOT / 'docs').rglob('*.md')))
#: a command as written for a user to run: in backticks, or at the start of a line of a code block
SUGGESTION = re.compile(r'(?:`|^\s*(?:\$ )?)(?:\.venv/bin/)?wind-shaper ([a-z][a-z-]*(?: [a-z][a-z-]*)?)',
                        re.M)


def suggested_commands() -> list[str]:
    found = set()
    for path in SOURCES:
        for match in SUGGESTION.finditer(path.read_text()):
            found.add(match.group(1))
    return sorted(found)


def command_words(words: str) -> list[str]:
    """The leading words of ``words`` that name a command or subcommand of the CLI."""
    parser, chosen = build_parser(), []
    for word in words.split():
        actions = [a for a in parser._actions if a.__class__.__name__ == '_SubParsersAction']
        if not actions or word not in actions[0].choices:
            break
        chosen.append(word)
        parser = actions[0].choices[word]
    return chosen


#: a script the docs tell a user to run: bench/NAME.py or tools/NAME.py
SCRIPT = re.compile(r'\b((?:bench|tools)/[a-z_]+\.py)\b')
DOCS = [ROOT / 'README.md'] + sorted((ROOT / 'docs').rglob('*.md'))


def shown_scripts() -> list[str]:
    return sorted({m.group(1) for path in DOCS for m in SCRIPT.finditer(path.read_text())})


def test_the_sources_suggest_commands():
    assert {'up', 'iterate', 'shape', 'model diagnose'} <= set(suggested_commands())  # the scan works


@pytest.mark.parametrize('words', suggested_commands())
def test_a_suggested_command_exists(words, capsys):
    chosen = command_words(words)  # the words after the command may be its arguments
    assert chosen, f'`wind-shaper {words}` is suggested, but the CLI has no command {words.split()[0]!r}'
    with pytest.raises(SystemExit) as done:
        main(chosen + ['--help'])
    assert done.value.code == 0
    assert 'usage: wind-shaper' in capsys.readouterr().out


def test_the_docs_show_scripts():
    assert {'bench/convergence.py', 'bench/detection.py', 'tools/readme_figure.py'} <= set(shown_scripts())


@pytest.mark.parametrize('script', shown_scripts())
def test_a_script_the_docs_show_has_help(script, capsys):
    """In-process (its main(['--help'])), so the imports are shared: the environment a script sets
    on import (BLAS threads) is put back."""
    path = ROOT / script
    assert path.is_file(), f'the docs show {script}, which does not exist'
    keep = dict(os.environ)
    spec = importlib.util.spec_from_file_location(f'shown_{path.stem}', path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module   # dataclasses look their module up there
    try:
        spec.loader.exec_module(module)
        with pytest.raises(SystemExit) as done:
            module.main(['--help'])
    finally:
        sys.modules.pop(spec.name, None)
        os.environ.clear()
        os.environ.update(keep)
    assert done.value.code == 0
    assert 'usage:' in capsys.readouterr().out


def test_targets_template_writes_a_profile_a_run_accepts(tmp_path, capsys):
    from wind_shaper.app import Setup
    out = tmp_path / 'profile.csv'
    assert main(['targets', 'template', str(out), '--start', 'parabolic']) == 0
    assert f'--target csv:{out}' in capsys.readouterr().out
    setup = Setup.load()
    kp = setup.geometry.key_points
    from_csv = setup.make_target(f'csv:{out}').values(kp)
    assert np.allclose(from_csv, setup.make_target('parabolic').values(kp))
    # an existing file is kept unless --force
    before = out.read_text()
    assert main(['targets', 'template', str(out)]) == 2
    assert 'exists' in capsys.readouterr().err and out.read_text() == before
    assert main(['targets', 'template', str(out), '--force']) == 0
    assert np.allclose(setup.make_target(f'csv:{out}').values(kp), 2.5)
