"""The documentation's test (marker ``docs``): docs/ builds with Sphinx with warnings as errors, every
relative link, anchor and image of README.md and docs/*.md resolves, the README stays a front
page, and no page speaks of development sessions or issue numbers.

Run it alone with ``bash tools/dev.sh test -m docs``. The `wind-shaper` commands and bench/tools
scripts the docs show are run with ``--help`` by test/e2e/test_suggested_commands.py.
"""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.docs

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / 'docs'
PAGES = [ROOT / 'README.md'] + sorted(DOCS.glob('*.md')) + sorted((DOCS / 'api').glob('*.md'))

FENCE = re.compile(r'^(```|~~~).*?^\1', re.M | re.S)
INLINE_CODE = re.compile(r'`[^`\n]*`')
#: [text](target) and ![alt](target); the target up to whitespace or ')'
LINK = re.compile(r'!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+"[^"]*")?\s*\)')
HTML_SRC = re.compile(r'<img[^>]*\bsrc="([^"]+)"', re.I)
HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$', re.M)


def prose(text: str) -> str:
    """The text without fenced code blocks and inline code (links there are not links)."""
    return INLINE_CODE.sub('', FENCE.sub('', text))


def slug(title: str) -> str:
    """The anchor of a heading as MyST (myst_heading_anchors) and GitHub make it."""
    text = re.sub(r'`([^`]*)`', r'\1', title)                  # inline code: its text
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', text)       # links: their text
    text = re.sub(r'\*{1,2}([^*]+)\*{1,2}', r'\1', text)          # emphasis (*, **)
    return re.sub(r'[^\w\- ]', '', text.strip().lower().replace(' ', '-'))


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file (MyST makes them for levels 1-3, see docs/conf.py)."""
    return {slug(m.group(2)) for m in HEADING.finditer(FENCE.sub('', path.read_text()))
            if len(m.group(1)) <= 3}


def links(path: Path) -> list[str]:
    text = prose(path.read_text())
    return LINK.findall(text) + HTML_SRC.findall(text)


def test_the_link_scan_works():
    readme = links(ROOT / 'README.md')
    assert 'docs/field_before_after.png' in readme and 'docs/getting-started.md' in readme
    assert slug('The field for a robot (field_estimator, service `/wind_shaper/field/query`)') == \
        'the-field-for-a-robot-field_estimator-service-wind_shaperfieldquery'


@pytest.mark.parametrize('page', PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_image_resolves(page):
    broken = []
    for target in links(page):
        if re.match(r'[a-z][a-z0-9+.-]*:', target):      # http:, https:, mailto:
            continue
        where, _, anchor = target.partition('#')
        file = (page.parent / where).resolve() if where else page
        if not file.exists():
            broken.append(f'{target}: no file {file.relative_to(ROOT) if ROOT in file.parents else file}')
        elif anchor and file.suffix == '.md' and anchor not in anchors(file):
            broken.append(f'{target}: no heading with anchor #{anchor} in {file.relative_to(ROOT)}')
    assert not broken, f'{page.relative_to(ROOT)}: ' + '; '.join(broken)


def test_every_docs_page_is_in_the_guide():
    """Sphinx warns about a page in no toctree too; this says which, without a build."""
    index = (DOCS / 'index.md').read_text()
    listed = set(re.findall(r'^([\w/-]+)\s*$', index.split('{toctree}')[1].split('```')[0], re.M))
    pages = {p.stem for p in DOCS.glob('*.md')} - {'index'}
    assert pages <= listed, f'pages missing from docs/index.md\'s toctree: {sorted(pages - listed)}'


def test_the_readme_is_a_front_page():
    lines = (ROOT / 'README.md').read_text().splitlines()
    assert len(lines) <= 200, f'README.md has {len(lines)} lines: move detail into docs/ (at most 200)'
    text = '\n'.join(lines)
    assert 'bash tools/dev.sh demo' in text and 'bash tools/dev.sh test' in text


def test_no_development_history_wording():
    """User-facing text speaks to a lab: no "session N", no issue numbers (history is CHANGELOG.rst's)."""
    wording = re.compile(r'\bsessions? \d+|\bissues? \d+|(?<![\w&\'"/])#\d+\b', re.I)
    found = []
    for path in ([ROOT / 'README.md'] + sorted(DOCS.rglob('*.md')) + sorted(DOCS.rglob('*.py'))
                 + sorted((ROOT / 'wind_shaper').rglob('*.py')) + sorted((ROOT / 'bench').glob('*.py'))):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if wording.search(line):
                found.append(f'{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}')
    assert not found, '\n'.join(found)


@pytest.mark.timeout(600)
def test_the_docs_build_with_warnings_as_errors(tmp_path):
    """Sphinx + MyST, -W: a broken cross-reference, a page in no toctree or a docstring autodoc
    cannot import fails here. Built from a copy so the API stubs land in the temporary folder."""
    pytest.importorskip('sphinx', reason='tools/requirements-docs.txt is not installed: bash tools/dev.sh setup')
    pytest.importorskip('myst_parser', reason='tools/requirements-docs.txt is not installed: bash tools/dev.sh setup')
    src = tmp_path / 'docs'
    shutil.copytree(DOCS, src, ignore=shutil.ignore_patterns('generated', '_build', '__pycache__'))
    done = subprocess.run([sys.executable, '-m', 'sphinx', '-W', '--keep-going', '-q', '-b', 'html',
                           str(src), str(tmp_path / 'html')],
                          capture_output=True, text=True, cwd=ROOT, timeout=580,
                          env={**os.environ, 'WIND_SHAPER_DOCS_ROOT': str(ROOT)})
    assert done.returncode == 0, f'sphinx failed (exit {done.returncode}):\n{done.stderr[-6000:]}'
    assert (tmp_path / 'html' / 'index.html').is_file()
    assert (tmp_path / 'html' / 'api' / 'generated' / 'wind_shaper.model.html').is_file()


def test_package_xml_parses():
    """rosdoc2 and colcon read package.xml: it must be well-formed (no "--" inside a comment)."""
    catkin_pkg = pytest.importorskip('catkin_pkg.package')
    package = catkin_pkg.parse_package(str(ROOT / 'package.xml'))
    assert package.name == 'wind_shaper' and 'python3-sphinx' in {d.name for d in package.doc_depends}


def test_the_changelog_has_a_dated_section_per_version_as_ros_tools_read_it():
    """CHANGELOG.rst in the catkin format: the released package.xml version has a section
    'X.Y.Z (YYYY-MM-DD)'; unreleased work sits under 'Forthcoming'."""
    changelog = pytest.importorskip('catkin_pkg.changelog')
    package = pytest.importorskip('catkin_pkg.package').parse_package(str(ROOT / 'package.xml'))
    parsed = changelog.get_changelog_from_path(str(ROOT / 'CHANGELOG.rst'))
    versions = {version: date for version, date, _ in parsed.foreach_version()}
    assert package.version in versions and versions[package.version] is not None, versions
    assert '\nForthcoming\n-----------\n' in (ROOT / 'CHANGELOG.rst').read_text()
