"""Hosts for tests and benchmarks of the graph across machines, on one machine: Linux network
namespaces joined by veth pairs through a bridge (root and iproute2 needed). Used by
test/graph/test_hosts.py and bench/hosts.py.

    hosts = Hosts('ws123', '10.77.20.')   # netns ws123h1..3 at 10.77.20.1-3/24, bridge ws123br
    hosts.create()
    subprocess.run([*hosts.exec(1), 'python', ...])
    hosts.link(1, up=False)               # pull host 1's cable
    hosts.remove()                        # kills what runs in them, deletes them and their links
"""
import os
import subprocess


def ip(*args, check=True):
    return subprocess.run(['ip', *args], check=check, capture_output=True, text=True, timeout=20)


class Hosts:
    """Three hosts (netns ``<tag>h1..3``) on one bridge (in netns ``<tag>br``), 10.77.x.1-3/24."""

    def __init__(self, tag, subnet):
        self.tag, self.subnet = tag, subnet
        self.bridge = f'{tag}br'

    def name(self, i):
        return f'{self.tag}h{i}'

    def nic(self, i):
        return f'{self.tag}e{i}'

    def exec(self, i):
        return ('ip', 'netns', 'exec', self.name(i))

    def create(self):
        ip('netns', 'add', self.bridge)
        inside = ('netns', 'exec', self.bridge, 'ip')
        ip(*inside, 'link', 'add', 'br0', 'type', 'bridge')
        ip(*inside, 'link', 'set', 'br0', 'type', 'bridge', 'mcast_snooping', '0')
        ip(*inside, 'link', 'set', 'br0', 'up')
        for i in (1, 2, 3):
            host, nic, port = self.name(i), self.nic(i), f'{self.tag}p{i}'
            ip('netns', 'add', host)
            ip('link', 'add', nic, 'type', 'veth', 'peer', 'name', port)
            ip('link', 'set', nic, 'netns', host)
            ip('link', 'set', port, 'netns', self.bridge)
            ip(*inside, 'link', 'set', port, 'master', 'br0')
            ip(*inside, 'link', 'set', port, 'up')
            on = ('netns', 'exec', host, 'ip')
            ip(*on, 'link', 'set', 'lo', 'up')
            ip(*on, 'addr', 'add', f'{self.subnet}{i}/24', 'dev', nic)
            ip(*on, 'link', 'set', nic, 'up')
            ip(*on, 'route', 'add', '224.0.0.0/4', 'dev', nic)   # DDS discovery's multicast

    def link(self, i, up: bool):
        ip('netns', 'exec', self.name(i), 'ip', 'link', 'set', self.nic(i), 'up' if up else 'down')

    def remove(self):
        """Kill what still runs in the hosts, then delete them (their veth ends go with them)."""
        for ns in [self.name(i) for i in (1, 2, 3)] + [self.bridge]:
            pids = ip('netns', 'pids', ns, check=False).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), 9)
                except (ProcessLookupError, ValueError):
                    pass
            ip('netns', 'delete', ns, check=False)
        left = [n for n in ip('netns', 'list', check=False).stdout.split() if n.startswith(self.tag)]
        if left:
            raise RuntimeError(f'network namespaces left behind: {left}')
