"""The iterate command's request (cli.service._IterationCall) without ROS: sent again while the
coordinator shows no iteration running, never again once one ran, and a busy refusal of a copy
does not end the call while the first request is open."""
from types import SimpleNamespace

import pytest

from wind_shaper.cli import service


class Future:
    def __init__(self):
        self.response = None

    def done(self):
        return self.response is not None

    def result(self):
        return self.response


class Client:
    def __init__(self):
        self.sent = []

    def call_async(self, request):
        self.sent.append(Future())
        return self.sent[-1]

    def remove_pending_request(self, future):
        pass


def reply(success, message=''):
    return SimpleNamespace(success=success, message=message)


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(service.time, 'monotonic', lambda: now[0])
    return now


def test_a_request_no_iteration_follows_goes_out_again(clock):
    client, status = Client(), [None, 0.0]
    call = service._IterationCall(client, object(), status, clock[0])
    clock[0] += service.RESEND_S + 0.1
    assert not call.poll() and len(client.sent) == 2
    client.sent[1].response = reply(True, 'k=3')
    assert call.poll() and call.answer.message == 'k=3'


def test_once_an_iteration_runs_nothing_more_is_sent(clock):
    client, status = Client(), [None, 0.0]
    call = service._IterationCall(client, object(), status, clock[0])
    clock[0] += 1.0
    status[:] = [SimpleNamespace(state='sweeping'), clock[0]]
    assert not call.poll()
    status[:] = [SimpleNamespace(state='done'), clock[0] + 1]   # its reply lost: still no copy
    for _ in range(10):
        clock[0] += service.RESEND_S
        assert not call.poll()
    assert len(client.sent) == 1


def test_a_status_from_before_the_request_does_not_count(clock):
    client = Client()
    status = [SimpleNamespace(state='sweeping'), clock[0] - 5.0]   # a latched one, older
    call = service._IterationCall(client, object(), status, clock[0])
    clock[0] += service.RESEND_S + 0.1
    call.poll()
    assert len(client.sent) == 2


def test_a_busy_copy_waits_for_the_first_request_and_a_lone_refusal_ends_the_call(clock):
    client, status = Client(), [None, 0.0]
    call = service._IterationCall(client, object(), status, clock[0])
    clock[0] += service.RESEND_S + 0.1
    call.poll()
    client.sent[1].response = reply(False, 'an iteration is running: wait for it or call ...')
    assert not call.poll()                       # the first request is still open
    client.sent[0].response = reply(True, 'k=1')
    assert call.poll() and call.answer.success

    other = service._IterationCall(client, object(), status, clock[0])
    client.sent[-1].response = reply(False, 'an iteration is running: wait for it or call ...')
    assert other.poll() and not other.answer.success   # somebody else's iteration: said at once


def test_status_before_any_iteration_says_so():
    status = SimpleNamespace(state='idle', iteration=-1, progress=0.0, target='parabolic',
                             rmse=float('nan'), fan_names=['A', 'B'], pwm=[0.5, 0.5],
                             run_folder='runs/default', samples=0, message='')
    text = service.format_status(status)
    assert text.startswith('coordinator: idle, no iteration yet') and '-1' not in text
    assert 'coordinator: done, iteration 3 (100%)' in service.format_status(
        SimpleNamespace(**{**vars(status), 'state': 'done', 'iteration': 3, 'progress': 1.0}))
