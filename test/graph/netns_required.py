"""What a test that makes network namespaces needs, checked once for every such test."""
import os
import shutil

import pytest


def require_netns(what: str) -> None:
    """Fail ``what`` where network namespaces cannot be made (CI runs as root: a missing
    requirement there is a failure, never a quiet skip), or skip it with WIND_SHAPER_NO_NETNS=1,
    which a developer without root sets to say so."""
    if os.geteuid() == 0 and shutil.which('ip') is not None:
        return
    if os.environ.get('WIND_SHAPER_NO_NETNS') == '1':
        pytest.skip(f'WIND_SHAPER_NO_NETNS=1: {what} is left out on this machine')
    pytest.fail(f'{what} needs root and iproute2 (ip netns) to make its hosts; run the suite as '
                f'root, or set WIND_SHAPER_NO_NETNS=1 to leave it out')
