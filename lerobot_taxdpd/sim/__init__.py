"""Procedural pybullet placement benchmarks: tasks, scripted experts, dataset generation and evaluation."""
