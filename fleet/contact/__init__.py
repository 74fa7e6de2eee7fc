"""Contact detection from position-only feedback (pure: no transport, no clocks).

``ContactDetector`` (``detector.py``) is fed targets, angle and status reports with their
times; ``config.py`` holds the inventory's thresholds; ``methods.py`` the five methods;
``predictor.py`` the model of the arm's command smoothing (method 5).
"""
