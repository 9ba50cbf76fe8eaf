"""The CLI's service call (cli.service._Session.call) against a real rclpy server in this
process: a request that gets no reply is sent again, and the first reply the caller accepts is
taken, so a request or reply DDS dropped (a restarted coordinator, a loaded machine) costs a
resend, not the command."""
import threading
import time

import pytest

pytestmark = pytest.mark.ros


@pytest.fixture
def trigger_server(ros_context):
    """A std_srvs/Trigger server; ``replies`` lists what the n-th request gets: a
    (success, message) pair, or None for no reply ever (the reply was lost)."""
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.task import Future
    from std_srvs.srv import Trigger
    node = __import__('rclpy').create_node('lossy_server', context=ros_context)
    state = {'replies': [], 'seen': 0}
    never = Future()

    async def handle(request, response):
        n = state['seen']
        state['seen'] += 1
        reply = state['replies'][n] if n < len(state['replies']) else (True, 'ok')
        if reply is None:
            await never   # this request is never answered
        response.success, response.message = reply
        return response

    # reentrant, as the coordinator's: an unanswered request does not hold up the next
    node.create_service(Trigger, 'lossy', handle, callback_group=ReentrantCallbackGroup())
    executor = MultiThreadedExecutor(context=ros_context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield state
    finally:
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()


def _call(timeout_s, **kwargs):
    from std_srvs.srv import Trigger

    from wind_shaper.cli.service import _Session
    with _Session() as session:
        client = session.node.create_client(Trigger, 'lossy')
        assert session.wait_for_service(client, 20.0), 'the test server did not appear'
        started = time.monotonic()
        answer = session.call(client, Trigger.Request(), timeout_s, **kwargs)
        return answer, time.monotonic() - started


def test_an_unanswered_request_is_sent_again_and_its_copy_answered(trigger_server):
    trigger_server['replies'] = [None, (True, 'second')]
    answer, _ = _call(20.0, resend_s=1.0)
    assert answer is not None and answer.message == 'second'
    assert trigger_server['seen'] >= 2


def test_without_resending_the_lost_reply_leaves_no_answer(trigger_server):
    trigger_server['replies'] = [None]
    answer, waited = _call(3.0, resend_s=0)
    assert answer is None and trigger_server['seen'] == 1
    assert waited >= 3.0


def test_a_refused_copy_waits_for_the_open_request(trigger_server):
    # the first request's reply is lost; a copy is refused as busy while it is open, and the
    # next copy is answered
    trigger_server['replies'] = [None, (False, 'busy: wait for it'), (True, 'recorded')]
    answer, _ = _call(20.0, resend_s=0.5, accept=lambda r: 'wait for it' not in r.message)
    assert answer.success and answer.message == 'recorded'
    assert trigger_server['seen'] == 3


def test_a_refusal_with_no_other_request_open_ends_the_call_at_once(trigger_server):
    trigger_server['replies'] = [(False, 'busy: wait for it')] * 100
    answer, waited = _call(20.0, resend_s=5.0, accept=lambda r: 'wait for it' not in r.message)
    assert answer is not None and not answer.success and 'wait for it' in answer.message
    assert waited < 5.0 and trigger_server['seen'] == 1
