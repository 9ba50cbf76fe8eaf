"""Symlink a setup.py's data_files into a prefix, as `colcon build --symlink-install` does.

An editable pip install (PEP 660) installs the code and console scripts but no data_files, so
the ament index marker, share/<pkg>/package.xml and share/<pkg>/config/* would be missing from
the virtual environment. This reads data_files from setup.py (by running it with setuptools.setup
replaced by a recorder) and links each file into PREFIX/<destination>/, so edits to those files
are live. Links made by an earlier run are listed in MANIFEST and removed first, so deleted or
renamed files leave no dangling links behind.

Usage: python tools/link_data_files.py REPO_ROOT PREFIX MANIFEST
"""
import os
import runpy
import sys

import setuptools


def read_data_files(repo_root):
    """Return setup.py's data_files as a list of (destination, [source paths relative to root])."""
    recorded = {}
    real_setup = setuptools.setup
    setuptools.setup = lambda **kwargs: recorded.update(kwargs)
    cwd = os.getcwd()
    try:
        os.chdir(repo_root)  # setup.py globs relative to its own directory
        runpy.run_path('setup.py', run_name='__main__')
    finally:
        os.chdir(cwd)
        setuptools.setup = real_setup
    if not recorded:
        raise SystemExit(f'{repo_root}/setup.py did not call setuptools.setup()')
    return recorded.get('data_files', [])


def main(argv):
    if len(argv) != 4:
        raise SystemExit(__doc__)
    repo_root, prefix, manifest = (os.path.abspath(a) for a in argv[1:])

    if os.path.exists(manifest):
        with open(manifest) as f:
            for link in f.read().splitlines():
                if link and os.path.islink(link):
                    os.unlink(link)

    links = []
    for destination, sources in read_data_files(repo_root):
        dest_dir = os.path.join(prefix, destination)
        os.makedirs(dest_dir, exist_ok=True)
        for source in sources:
            source_path = os.path.join(repo_root, source)
            if not os.path.isfile(source_path):
                continue  # glob() results are files; a directory entry is not a data file
            link = os.path.join(dest_dir, os.path.basename(source))
            if os.path.lexists(link):
                if not os.path.islink(link):
                    raise SystemExit(f'{link} exists and is not a link made by this script: '
                                     'remove it or run `bash tools/dev.sh clean`')
                os.unlink(link)
            os.symlink(source_path, link)
            links.append(link)

    with open(manifest, 'w') as f:
        f.write(''.join(link + '\n' for link in links))
    print(f'linked {len(links)} data file(s) into {prefix}')


if __name__ == '__main__':
    main(sys.argv)
