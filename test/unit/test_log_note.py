"""rclpy refuses two severities from one logging line; ``log_note`` gives each its own."""
import pytest
from rclpy.logging import get_logger

from wind_shaper.ros.log import log_note


def test_rclpy_refuses_a_second_severity_from_one_line():
    logger = get_logger('wind_shaper_test_one_line')
    with pytest.raises(ValueError, match='severity cannot be changed'):
        for warning in (False, True):
            (logger.warning if warning else logger.info)('a note')


def test_log_note_takes_either_severity_in_any_order():
    logger = get_logger('wind_shaper_test_log_note')
    for warning in (False, True, False, True):
        log_note(logger, warning, 'a note')
