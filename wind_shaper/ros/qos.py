"""QoS profiles. The force stream is reliable with a deep queue. Between processes at 1 kHz a
depth of 10 lost 0.2-0.7 % of samples; depth 100 lost 0.6 % in 1 of 7 runs on a loaded 2-core
machine (it rides out only a 100 ms stall); depth 1000 (about 100 kB of wrenches) was lossless in
every run (bench/force_stream.py)."""
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

STREAM = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
COMMAND = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: Latched: a late subscriber still gets the last status / command / estimate.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
