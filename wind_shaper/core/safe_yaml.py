"""YAML read within bounds: every YAML text wind_shaper reads goes through ``load_yaml``.

``yaml.safe_load`` builds no Python objects of the file's choosing, but it still expands
aliases (a 1 KB "billion laughs" of nested anchors became gigabytes), recurses once per level of
nesting (50,000 brackets end in RecursionError) and takes whatever size it is given. Here a text
is refused, before anything is built, when it is larger than ``Limits.yaml_bytes``, nests deeper
than ``Limits.yaml_depth``, or holds an anchor or an alias (no file wind_shaper writes has one);
the check runs over the parser's events, which need no recursion. Values YAML resolves but
Python cannot build (an integer of a million digits, a date of month 13) are refused as well.
Every refusal is a ``YamlRefused``: a ``yaml.YAMLError`` (so a reader's existing handling of
broken YAML applies) whose message says what was wrong and quotes at most a short excerpt.
"""
from __future__ import annotations

import contextlib
import gc
import threading
from pathlib import Path

import yaml

from .errors import LimitError
from .limits import DEFAULT_LIMITS, Limits, excerpt

#: libyaml's parser when PyYAML was built with it (5-10 times faster), else the Python one.
_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


class YamlRefused(yaml.YAMLError, LimitError):
    """A YAML text that is too large, too deep, uses anchors or aliases, or cannot be read."""


def load_yaml(text, source: str = 'the YAML text', limits: Limits = DEFAULT_LIMITS):
    """The document of ``text`` (str or bytes) as plain Python data (dicts, lists, str, numbers,
    bools, None, dates); YamlRefused when it breaks a bound or is not readable YAML."""
    if isinstance(text, (bytes, bytearray)):
        if len(text) > limits.yaml_bytes:
            raise _too_large(source, f'{len(text)} bytes', limits)
        try:
            text = bytes(text).decode('utf-8')
        except UnicodeDecodeError as exc:
            raise YamlRefused(f'{source} is not UTF-8 text (byte {exc.start}): save it as '
                              f'UTF-8') from None
    if not isinstance(text, str):
        raise YamlRefused(f'{source} must be text, not {type(text).__name__}')
    # a character is at least one byte: the length bounds the size without encoding a huge text
    if len(text) > limits.yaml_bytes:
        raise _too_large(source, f'{len(text)} characters', limits)
    try:
        size = len(text.encode('utf-8'))
    except UnicodeError:
        raise YamlRefused(f'{source} holds characters that are not valid Unicode (lone '
                          f'surrogates): send UTF-8 text') from None
    if size > limits.yaml_bytes:
        raise _too_large(source, f'{size} bytes', limits)
    _check_events(text, source, limits)
    try:
        with _collector_paused():
            return yaml.load(text, Loader=_LOADER)  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        raise YamlRefused(f'{source} is not readable YAML: {_short_error(exc)}') from None
    except (ValueError, OverflowError, TypeError, RecursionError, MemoryError) as exc:
        raise YamlRefused(f'{source} holds a value that cannot be read: {type(exc).__name__}: '
                          f'{excerpt(str(exc), quote=False)}') from None


def read_yaml_file(path, limits: Limits = DEFAULT_LIMITS):
    """``load_yaml`` of the file at ``path``, read only when its size is within the bound;
    OSError (missing, unreadable) passes through for the caller to word."""
    path = Path(path)
    with open(path, 'rb') as stream:
        data = stream.read(limits.yaml_bytes + 1)
    return load_yaml(data, str(path), limits)


def read_text_file(path, max_bytes: int | None = None, limits: Limits = DEFAULT_LIMITS) -> str:
    """The UTF-8 text of ``path`` when it has at most ``max_bytes`` (default
    ``limits.file_bytes``); LimitError when larger, OSError as open() raises it."""
    bound = limits.file_bytes if max_bytes is None else int(max_bytes)
    with open(path, 'rb') as stream:
        data = stream.read(bound + 1)
    if len(data) > bound:
        raise LimitError(f'{path} is larger than {bound} bytes (limits.file_bytes): this is not '
                         f'a file wind_shaper wrote or reads; give the right file')
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise LimitError(f'{path} is not UTF-8 text (byte {exc.start}): give the right file or '
                         f'save it as UTF-8') from None


_pause_lock = threading.Lock()
_pauses = 0
_was_enabled = False


@contextlib.contextmanager
def _collector_paused():
    """Python's cyclic garbage collector off while a document is built.

    A large text builds hundreds of thousands of lists and dicts; each gen-2 pass the allocations
    trigger walks every object of the process and holds the GIL throughout (0.3-0.4 s apiece for
    a 1 MB text on an idle machine, seconds on a busy one), so a node reading it in a worker
    thread stopped answering its services meanwhile. A loaded document holds no reference
    cycles, so the collector has nothing to find in it: paused, the read takes half the time and
    the longest pause of other threads falls to tens of milliseconds. Nested and concurrent
    reads share one pause; the collector's own state is restored by the last one out."""
    global _pauses, _was_enabled
    with _pause_lock:
        if _pauses == 0:
            _was_enabled = gc.isenabled()
            gc.disable()
        _pauses += 1
    try:
        yield
    finally:
        with _pause_lock:
            _pauses -= 1
            if _pauses == 0 and _was_enabled:
                gc.enable()


def _check_events(text: str, source: str, limits: Limits) -> None:
    depth = 0
    try:
        for event in yaml.parse(text, Loader=_LOADER):
            if isinstance(event, yaml.AliasEvent) or getattr(event, 'anchor', None) is not None:
                raise YamlRefused(f'{source} uses YAML anchors or aliases (&name, *name): '
                                  f'wind_shaper reads none (they can expand a small text '
                                  f'into gigabytes); write every value out')
            if isinstance(event, yaml.CollectionStartEvent):
                depth += 1
                if depth > limits.yaml_depth:
                    raise YamlRefused(f'{source} nests lists or mappings deeper than '
                                      f'{limits.yaml_depth} levels (limits.yaml_depth): no file '
                                      f'wind_shaper reads is that deep; check what was sent')
            elif isinstance(event, yaml.CollectionEndEvent):
                depth -= 1
    except yaml.YAMLError as exc:
        if isinstance(exc, YamlRefused):
            raise
        raise YamlRefused(f'{source} is not readable YAML: {_short_error(exc)}') from None
    except (UnicodeError, ValueError) as exc:
        raise YamlRefused(f'{source} is not readable YAML: {excerpt(str(exc), quote=False)}') from None


def _short_error(exc: yaml.YAMLError) -> str:
    """PyYAML's message without the quoted lines, which can repeat long input."""
    if isinstance(exc, yaml.MarkedYAMLError):
        parts = [exc.context or '', exc.problem or '']
        mark = exc.problem_mark or exc.context_mark
        where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark is not None else ''
        return excerpt(' '.join(p for p in parts if p) or 'malformed', 120, quote=False) + where
    return excerpt(str(exc), 120, quote=False)


def _too_large(source: str, size: str, limits: Limits) -> YamlRefused:
    return YamlRefused(f'{source} has {size}, more than the {limits.yaml_bytes} allowed '
                       f'(limits.yaml_bytes): no model file, design or run description is that '
                       f'large; check what was sent')


__all__ = ['YamlRefused', 'load_yaml', 'read_text_file', 'read_yaml_file']
