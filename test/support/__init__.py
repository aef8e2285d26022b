"""Test helpers (not tests): the multi-process ROS harness, the launch-file evaluator, the tf2_msgs builder."""
