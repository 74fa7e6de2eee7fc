"""Leader/follower teleoperation (D1-T): a leader moved by hand, followers that copy it."""
