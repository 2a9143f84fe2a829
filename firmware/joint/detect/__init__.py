"""What the joint watches: the original's stall detector (stall.py), the tracking detector
(tracking.py), the homing monitor (homing.py) and the debug trace's line (trace_line.py).
May import motion and micro."""
