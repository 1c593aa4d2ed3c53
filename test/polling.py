"""Waiting in tests for something another thread or process does."""
import time


def wait_until(condition, timeout_s: float = 5.0, poll_s: float = 0.02) -> bool:
    """Poll ``condition()`` until it holds (True) or ``timeout_s`` of wall time pass (False)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(poll_s)
    return False
