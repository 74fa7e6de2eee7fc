"""Contact detection from position-only feedback (pure: no transport, no clocks).

``ContactDetector`` (``detector.py``) is fed targets, angle and status reports with their
times; ``config.py`` holds the inventory's thresholds; ``methods.py`` the five methods;
``predictor.py`` method 5's model of the arm's response (``dynamics.py``, shared with the
simulator), trusted only with a calibration (``calibration.py``, ``fit.py``) and while the online
check (``sanity.py``) finds it right in free motion.
"""
