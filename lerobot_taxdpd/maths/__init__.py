"""Geometry and the metrics every report uses (numpy and torch, no LeRobot)."""
