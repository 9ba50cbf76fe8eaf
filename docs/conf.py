"""Sphinx configuration of wind_shaper's documentation (MyST Markdown, the tooling rosdoc2 uses).

Build it with warnings as errors (what test/unit/test_docs.py does):

    .venv/bin/python -m sphinx -W --keep-going -b html docs build/docs

The API pages are generated from the docstrings (autosummary, into docs/api/generated/, which
git ignores). wind_shaper's docstrings are plain text, not reStructuredText (formulas such as
|x| or U_j^2 are written as they read), so each one is shown as a literal block.
"""
import os
import sys

# the repository (a test builds a copy of docs/ elsewhere and names the repository here)
ROOT = os.environ.get('WIND_SHAPER_DOCS_ROOT') or os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

project = 'wind_shaper'
author = 'wind_shaper developers'
copyright = '2026, wind_shaper developers'
try:  # the version of package.xml, as rosdoc2 shows it
    import re
    with open(os.path.join(ROOT, 'package.xml')) as f:
        release = version = re.search(r'<version>([^<]+)</version>', f.read()).group(1)
except (OSError, AttributeError):
    release = version = ''

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.autosummary',
]
source_suffix = {'.rst': 'restructuredtext', '.md': 'markdown'}
root_doc = 'index'
exclude_patterns = ['_build', 'examples']
myst_heading_anchors = 3
myst_enable_extensions = ['colon_fence']

autosummary_generate = True
autodoc_default_options = {'members': True, 'ignore-module-all': True}
autodoc_typehints = 'signature'
autodoc_member_order = 'bysource'

html_theme = 'alabaster'
html_title = f'wind_shaper {release}'
html_show_sourcelink = False


def _docstring_as_written(app, what, name, obj, options, lines):
    """Show a plain-text docstring as it is written (a literal block), not parsed as reST."""
    if not any(line.strip() for line in lines):
        return
    text = list(lines)
    lines[:] = ['::', ''] + [('    ' + line) if line.strip() else '' for line in text] + ['']


def setup(app):
    app.connect('autodoc-process-docstring', _docstring_as_written)
