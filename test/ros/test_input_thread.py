"""InputThread: subscriptions served in a thread of their own (the planner's input topics)."""

import os
import threading
import time

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Int32

from tocontrol_ros.nodes.input_thread import InputThread

pytestmark = pytest.mark.ros
NAMESPACE = f"/inputs_{os.getpid()}"
#: A wait that only catches a hang (s): never a claim about speed.
HANG = 60.0


def test_callbacks_run_in_the_thread_one_at_a_time_and_survive_an_exception():
    """Messages are served by the thread (no other executor spins), a callback that raises
    is logged and the next message is still served, and destroy stops the thread."""
    context = rclpy.Context()
    rclpy.init(context=context)
    owner = Node("owner", namespace=NAMESPACE, context=context)
    sender = Node("sender", namespace=NAMESPACE, context=context)
    errors, seen, threads = [], [], set()
    busy = threading.Lock()
    overlapped = []
    done = threading.Event()

    def on_message(msg):
        if not busy.acquire(blocking=False):
            overlapped.append(msg.data)
            return
        try:
            threads.add(threading.current_thread())
            time.sleep(0.01)  # long enough for a second message to overlap if it could
            if msg.data == 1:
                raise ValueError("a bad message")
            seen.append(msg.data)
            if msg.data == 4:
                done.set()
        finally:
            busy.release()

    inputs = InputThread(owner, "inputs", errors.append)
    try:
        inputs.subscribe(Int32, "~/numbers", on_message, 10)
        assert inputs.topics == [f"{NAMESPACE}/owner/numbers"]
        inputs.start()
        pub = sender.create_publisher(Int32, f"{NAMESPACE}/owner/numbers", 10)
        deadline = time.monotonic() + HANG
        while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(5):
            pub.publish(Int32(data=i))
        assert done.wait(HANG), (seen, errors)
        assert seen == [0, 2, 3, 4] and overlapped == []
        assert threads == {inputs.thread}
        assert len(errors) == 1 and "a bad message" in errors[0]
    finally:
        inputs.destroy()
        assert not inputs.thread.is_alive()
        sender.destroy_node()
        owner.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_context_shut_down_ends_the_thread():
    """rclpy.shutdown of the context while the thread waits: it ends, and destroy after it
    still returns."""
    context = rclpy.Context()
    rclpy.init(context=context)
    owner = Node("owner2", namespace=NAMESPACE, context=context)
    inputs = InputThread(owner, "inputs", lambda _msg: None)
    inputs.subscribe(Int32, "~/numbers", lambda _msg: None, 10)
    inputs.start()
    rclpy.try_shutdown(context=context)
    inputs.thread.join(HANG)
    assert not inputs.thread.is_alive()
    inputs.destroy()
