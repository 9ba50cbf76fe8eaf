"""Log a message whose severity is decided at run time.

rclpy keys each logging call by its call site and refuses a second severity from the same line
("Logger severity cannot be changed between calls"): a line that picks ``warning`` or ``info``
by a condition raises the first time the condition differs from its first call. Here each
severity has its own line."""
from __future__ import annotations


def log_note(logger, warning: bool, message: str) -> None:
    """``message`` as a warning when ``warning``, else as information, on an rclpy logger."""
    if warning:
        logger.warning(message)
    else:
        logger.info(message)


__all__ = ['log_note']
