"""Run the node graph as separate OS processes and look after them (no argparse, no rclpy).

``Supervisor`` starts the processes of the plan (``plan.plan_graph``), each in its own session
(a Ctrl-C in the terminal reaches only the supervisor, which then stops the children in order)
and, on Linux, with a parent-death signal (if the supervisor itself is killed, its children get SIGTERM
instead of running on). Every line a child prints is echoed with the node's name in front and
kept in a tail for error reports.

``Supervisor.wait_visible(visible)`` waits (bounded) until every node appears in the ROS graph:
``visible()`` is injected (``wind_shaper.cli.graph`` asks rclpy), so this module stays free of
ROS. ``start(names)`` and ``wait_visible(..., names=)`` bring the graph up in stages (the
simulated rig first, so the drivers find its sockets open).

``poll()`` notices a child that died, reports its exit code and log tail and restarts it after a
backoff (``RestartPolicy``); a node that exits with code 2 (a configuration error: the node
runner's convention) or that used up its restarts is given up, which ends the graph. A child
that is alive but hung is treated as dead: each node touches a heartbeat file while its executor
runs (``core.heartbeat``, called by ``wind_shaper.ros.runner``), and one whose heartbeat is
older than ``RestartPolicy.hang_after_s`` is killed (SIGKILL) and so restarted. (Seen: a node whose
publish blocked forever in Fast DDS's shared-memory transport after the subscriber it was
sending to had been killed; its stream was gone for good until the node was restarted.)
A child can also be alive, beating, and deaf: its executor waits and no call from another
process reaches it (seen, rarely, for a field_estimator restarted mid-sweep). With
``RestartPolicy.deaf_after_s`` and a probe (``Supervisor.watch_answers``: another process calls
each node, e.g. its parameter service, and reports when it last answered), a node that has not
answered for that long is killed and restarted the same way.
``shutdown()`` sends SIGINT to every child, waits ``grace_s``, then SIGKILLs what is left.
"""
from __future__ import annotations

import collections
import ctypes
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence, TextIO

from ..core.errors import WindShaperError
from ..core.heartbeat import HEARTBEAT_ENV
from .plan import GraphError, NodeSpec, graph_env

__all__ = ['RestartPolicy', 'Supervisor', 'NodeGaveUp', 'Stopped', 'StopSignals',
           'CONFIG_ERROR_EXIT']

#: Exit code of a node whose configuration is wrong (``wind_shaper.ros.runner``): never restarted.
CONFIG_ERROR_EXIT = 2
_PR_SET_PDEATHSIG = 1


class NodeGaveUp(WindShaperError):
    """A node died and will not be restarted (restarts used up, disabled, or a config error)."""


class Stopped(Exception):
    """A wait was ended by a stop request (Ctrl-C / SIGTERM): not an error."""


# ------------------------------------------------------------------------------------- policy
@dataclass(frozen=True)
class RestartPolicy:
    """Restart a node that died: ``enabled``; at most ``max_restarts`` times per node; after
    ``backoff_s`` [s], doubling each time up to ``max_backoff_s``; a node that ran for
    ``reset_after_s`` [s] since its last start has its count reset (a crash a day is not a
    crash loop); a node whose heartbeat is older than ``hang_after_s`` [s] is hung and is
    killed, so that it is restarted like one that died (0: never; it must exceed the longest
    callback a node runs, an estimate of a large wall takes seconds); a node that has answered
    no probe call for ``deaf_after_s`` [s] since its start or its last answer is deaf and is
    killed likewise (0: never; it needs a probe, ``Supervisor.watch_answers``)."""

    enabled: bool = True
    max_restarts: int = 3
    backoff_s: float = 1.0
    max_backoff_s: float = 10.0
    reset_after_s: float = 300.0
    hang_after_s: float = 0.0
    deaf_after_s: float = 0.0

    def __post_init__(self):
        if (self.max_restarts < 0 or self.backoff_s < 0 or self.max_backoff_s < 0
                or self.hang_after_s < 0 or self.deaf_after_s < 0):
            raise ValueError(f'restart policy values must be >= 0; got {self}')

    def delay(self, restarts_so_far: int) -> float:
        """Wait [s] before restart number ``restarts_so_far + 1``."""
        return min(self.backoff_s * 2 ** restarts_so_far, self.max_backoff_s)


# ------------------------------------------------------------------------------------ children
def _parent_death_signal():
    """preexec_fn: on Linux, SIGTERM this child when the thread that forked it exits (the
    supervisor spawns from its main thread only). None elsewhere."""
    if not sys.platform.startswith('linux'):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None

    def arm():
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    return arm


@dataclass
class _Child:
    spec: NodeSpec
    tail: collections.deque
    process: subprocess.Popen | None = None
    reader: threading.Thread | None = None
    started_at: float = 0.0
    restarts: int = 0
    restart_at: float | None = None
    exit_code: int | None = None
    gave_up: bool = False
    hung: bool = False
    deaf: bool = False
    pids: list = field(default_factory=list)


class Supervisor:
    """Starts, watches, restarts and stops the node processes of ``specs`` (see module doc).

    env: the children's environment (``graph_env()``); out: where prefixed child lines and
    reports go; policy: ``RestartPolicy``; tail_lines: lines kept per node for reports;
    log_dir: if given, each node's output is also written to ``log_dir/<node>.log``;
    grace_s [s]: how long ``shutdown`` waits after SIGINT before SIGKILL.
    """

    def __init__(self, specs: Sequence[NodeSpec], *, env: Mapping[str, str] | None = None,
                 out: TextIO | None = None, policy: RestartPolicy = RestartPolicy(),
                 tail_lines: int = 20, log_dir: Path | None = None, grace_s: float = 5.0,
                 clock: Callable[[], float] = time.monotonic):
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise GraphError(f'node names must be unique; got {names}')
        self.specs = list(specs)
        self.env = dict(graph_env() if env is None else env)
        self.out = out or sys.stdout
        self.policy = policy
        self.log_dir = Path(log_dir) if log_dir else None
        self.grace_s = float(grace_s)
        self.clock = clock
        self._children = {s.name: _Child(s, collections.deque(maxlen=tail_lines)) for s in specs}
        self._width = max((len(n) for n in names), default=0)
        self._out_lock = threading.Lock()
        self._preexec = _parent_death_signal()
        self._stopping = False
        self._beats = (Path(tempfile.mkdtemp(prefix='wind_shaper_up_')) if policy.hang_after_s > 0
                       else None)
        self._probe: Callable[[Sequence[str]], Mapping[str, float]] | None = None

    def watch_answers(self, probe: Callable[[Sequence[str]], Mapping[str, float]]) -> None:
        """Judge deafness (``RestartPolicy.deaf_after_s``) by ``probe(names)``: called every poll
        with the nodes running now, it sends them its calls as it sees fit and returns {node:
        the ``clock()`` time of its last answer} (a node never answered may be left out)."""
        self._probe = probe

    # ------------------------------------------------------------------ output
    def say(self, text: str) -> None:
        """A line of the supervisor's own, between the children's lines."""
        with self._out_lock:
            self.out.write(text.rstrip('\n') + '\n')
            self.out.flush()

    def _pump(self, child: _Child, stream, log) -> None:
        prefix = f'[{child.spec.name:<{self._width}}] '
        try:
            for raw in iter(stream.readline, b''):
                line = raw.decode('utf-8', 'replace').rstrip('\r\n')
                child.tail.append(line)
                if log is not None:
                    log.write(line + '\n')
                    log.flush()
                with self._out_lock:
                    self.out.write(prefix + line + '\n')
                    self.out.flush()
        except (OSError, ValueError):
            pass
        finally:
            stream.close()
            if log is not None:
                log.close()

    # ------------------------------------------------------------------ processes
    def _spawn(self, child: _Child) -> None:
        spec = child.spec
        log = None
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            log = open(self.log_dir / f'{spec.name}.log', 'a', encoding='utf-8')
        if threading.current_thread() is not threading.main_thread():
            preexec = None   # the parent-death signal follows the forking thread: main only
        else:
            preexec = self._preexec
        env = self.env
        if self._beats is not None:
            beat = self._beats / spec.name
            beat.unlink(missing_ok=True)   # the new process beats for itself
            env = {**env, HEARTBEAT_ENV: str(beat)}
        try:
            process = subprocess.Popen(spec.argv, env=env, stdin=subprocess.DEVNULL,
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                       start_new_session=True, preexec_fn=preexec)
        except OSError as exc:
            if log is not None:
                log.close()
            raise GraphError(f'cannot start node {spec.name} ({" ".join(spec.argv[:3])}...): '
                             f'{exc}') from None
        child.process, child.exit_code, child.restart_at = process, None, None
        child.hung = child.deaf = False
        child.started_at = self.clock()
        child.pids.append(process.pid)
        child.reader = threading.Thread(target=self._pump, args=(child, process.stdout, log),
                                        name=f'supervisor-{spec.name}', daemon=True)
        child.reader.start()

    def start(self, names: Iterable[str] | None = None) -> None:
        """Start the nodes ``names`` (default: every node not started yet), in plan order."""
        wanted = None if names is None else set(names)
        unknown = (wanted or set()) - set(self._children)
        if unknown:
            raise GraphError(f'no node {sorted(unknown)} in this graph')
        for name, child in self._children.items():
            if child.process is not None or (wanted is not None and name not in wanted):
                continue
            if child.spec.note:
                self.say(f'wind-shaper up: {child.spec.note}')
            self._spawn(child)

    def pids(self) -> dict[str, int]:
        """PIDs of the children running now."""
        return {n: c.process.pid for n, c in self._children.items()
                if c.process is not None and c.process.poll() is None}

    def all_pids(self) -> list[int]:
        """Every PID this supervisor ever started (restarts included)."""
        return [pid for c in self._children.values() for pid in c.pids]

    def tail(self, name: str, lines: int | None = None) -> list[str]:
        """The last lines [of at most ``lines``] node ``name`` printed."""
        child = self._children[name]
        if child.reader is not None and child.process is not None and child.process.poll() is not None:
            child.reader.join(1.0)   # let the last lines of a dead child arrive
        out = list(child.tail)
        return out[-lines:] if lines else out

    def _tail_text(self, name: str) -> str:
        lines = self.tail(name)
        return '\n'.join(f'    {ln}' for ln in lines) if lines else '    (it printed nothing)'

    # ------------------------------------------------------------------ start-up
    def wait_visible(self, visible: Callable[[], Iterable[str]], timeout_s: float = 60.0,
                     interval_s: float = 0.1, names: Iterable[str] | None = None,
                     should_stop: Callable[[], bool] | None = None) -> float:
        """Wait until the name of every started node (or of each of ``names``) is in
        ``visible()``; returns the time it took [s]. GraphError naming the node (with its log
        tail) if one exits first or is not visible within ``timeout_s``; Stopped as soon as
        ``should_stop()``."""
        t0 = self.clock()
        wanted = [n for n, c in self._children.items() if c.process is not None
                  and (names is None or n in set(names))]
        while True:
            if should_stop is not None and should_stop():
                raise Stopped('stopped while the graph was starting')
            for name in wanted:
                code = self._children[name].process.poll()
                if code is not None:
                    raise GraphError(f'node {name} exited with code {code} while the graph was '
                                     f'starting; its last lines:\n{self._tail_text(name)}')
            seen = set(visible())
            missing = [n for n in wanted if n not in seen]
            if not missing:
                return self.clock() - t0
            if self.clock() - t0 > timeout_s:
                name = missing[0]
                others = f' (also missing: {", ".join(missing[1:])})' if missing[1:] else ''
                raise GraphError(f'node {name} did not appear in the ROS graph within '
                                 f'{timeout_s:g} s{others}; visible: '
                                 f'{", ".join(sorted(seen & set(wanted))) or "none"}. Check '
                                 f'ROS_DOMAIN_ID / discovery settings; its last lines:\n'
                                 f'{self._tail_text(name)}')
            time.sleep(interval_s)

    # ------------------------------------------------------------------ supervision
    def poll(self) -> None:
        """Report children that died and restart them when due (call from the main thread every
        ~0.1 s). Raises NodeGaveUp when a node will not be restarted."""
        now = self.clock()
        answered = self._answers()
        for name, child in self._children.items():
            if child.gave_up or child.process is None:
                continue
            if child.restart_at is not None:
                if now >= child.restart_at:
                    child.restarts += 1
                    self._spawn(child)
                    self.say(f'wind-shaper up: restarting {name} '
                             f'({child.restarts} of {self.policy.max_restarts}): pid '
                             f'{child.process.pid}')
                continue
            code = child.process.poll()
            if code is None:
                self._kill_if_hung(name, child, now)
                self._kill_if_deaf(name, child, now, answered)
                continue
            if child.exit_code is not None:
                continue
            child.exit_code = code
            if now - child.started_at >= self.policy.reset_after_s:
                child.restarts = 0
            report = (f'wind-shaper up: node {name} (pid {child.process.pid}) exited with code '
                      f'{code}; its last lines:\n{self._tail_text(name)}')
            if child.hung:
                report = (f'wind-shaper up: node {name} (pid {child.process.pid}) was killed: '
                          f'hung (no heartbeat for {self.policy.hang_after_s:g} s)')
            elif child.deaf:
                report = (f'wind-shaper up: node {name} (pid {child.process.pid}) was killed: '
                          f'deaf (no answer for {self.policy.deaf_after_s:g} s)')
            if code == CONFIG_ERROR_EXIT:
                reason = 'it reported a configuration error: fix it and start again'
            elif not self.policy.enabled:
                reason = 'restarts are off'
            elif child.restarts >= self.policy.max_restarts:
                reason = f'it was restarted {child.restarts} times already'
            else:
                delay = self.policy.delay(child.restarts)
                child.restart_at = now + delay
                self.say(f'{report}\nwind-shaper up: restarting {name} in {delay:g} s')
                continue
            child.gave_up = True
            self.say(report)
            raise NodeGaveUp(f'node {name} exited with code {code} and is not restarted: {reason}')

    def _kill_if_hung(self, name: str, child: _Child, now: float) -> None:
        """SIGKILL a running child whose heartbeat is older than ``hang_after_s`` (or that has
        not beaten within that long of its start); the next poll restarts it."""
        hang_after = self.policy.hang_after_s
        if self._beats is None or child.hung or now - child.started_at < hang_after:
            return
        try:
            age = time.time() - (self._beats / name).stat().st_mtime
        except OSError:
            age = now - child.started_at          # never beat since it started
        if age < hang_after:
            return
        child.hung = True
        self._kill_to_restart(name, child, f'has not run its executor for {age:.0f} s (no '
                              f'heartbeat; --hang-after {hang_after:g} s): it is hung')

    def _answers(self) -> Mapping[str, float]:
        """The probe's last answer per running node ({} without a probe or deaf_after_s)."""
        if self._probe is None or self.policy.deaf_after_s <= 0 or self._stopping:
            return {}
        running = [n for n, c in self._children.items() if c.process is not None
                   and c.restart_at is None and not c.gave_up and c.process.poll() is None]
        return self._probe(running) if running else {}

    def _kill_if_deaf(self, name: str, child: _Child, now: float, answered: Mapping[str, float]) -> None:
        """SIGKILL a running child that has answered no probe call for ``deaf_after_s`` since its
        start or its last answer; the next poll restarts it."""
        deaf_after = self.policy.deaf_after_s
        if self._probe is None or deaf_after <= 0 or child.hung or child.deaf:
            return
        last = max(answered.get(name, float('-inf')), child.started_at)
        if now - last < deaf_after:
            return
        child.deaf = True
        since = 'since it started' if last == child.started_at else 'since its last answer'
        self._kill_to_restart(name, child, f'is running but has answered no call for '
                              f'{now - last:.0f} s ({since}; --deaf-after {deaf_after:g} s): it '
                              f'is deaf to the graph')

    def _kill_to_restart(self, name: str, child: _Child, why: str) -> None:
        """Say why a running child is killed, with its last lines, and SIGKILL it; the next poll
        restarts it like a node that died."""
        self.say(f'wind-shaper up: node {name} (pid {child.process.pid}) {why}; killing it so '
                 f'that it is restarted; its last lines:\n{self._tail_text(name)}')
        try:
            child.process.kill()
        except ProcessLookupError:
            pass

    def supervise(self, should_stop: Callable[[], bool], interval_s: float = 0.1,
                  during: Callable[[], None] | None = None) -> None:
        """Poll until ``should_stop()``; ``during()`` is called each round (e.g. to check on a
        job). NodeGaveUp propagates."""
        while not should_stop():
            self.poll()
            if during is not None:
                during()
            time.sleep(interval_s)

    # ------------------------------------------------------------------ shutdown
    def shutdown(self, grace_s: float | None = None) -> dict[str, int | None]:
        """SIGINT to every child still running, wait up to ``grace_s`` [s], SIGKILL the rest;
        returns {node: exit code}. Safe to call more than once."""
        grace = self.grace_s if grace_s is None else float(grace_s)
        self._stopping = True
        running = [c for c in self._children.values()
                   if c.process is not None and c.process.poll() is None]
        for child in running:
            try:
                child.process.send_signal(signal.SIGINT)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + grace
        for child in running:
            try:
                child.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for child in running:
            if child.process.poll() is None:
                self.say(f'wind-shaper up: {child.spec.name} did not stop within {grace:g} s of '
                         f'SIGINT: killing it')
                child.process.kill()
                child.process.wait(5.0)
        for child in self._children.values():
            if child.reader is not None:
                child.reader.join(2.0)
        if self._beats is not None:
            shutil.rmtree(self._beats, ignore_errors=True)
        return {n: (c.process.returncode if c.process is not None else None)
                for n, c in self._children.items()}


# ------------------------------------------------------------------------------------- signals
class StopSignals:
    """Context manager: while active, SIGINT and SIGTERM set ``event`` instead of raising
    (a second one raises KeyboardInterrupt, for a user who insists). Main thread only."""

    def __init__(self):
        self.event = threading.Event()
        self.signal: int | None = None
        self._old = {}

    def _handle(self, signum, frame):
        if self.event.is_set():
            raise KeyboardInterrupt
        self.signal = signum
        self.event.set()

    def __enter__(self) -> 'StopSignals':
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def __call__(self) -> bool:
        return self.event.is_set()
