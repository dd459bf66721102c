"""Simulation for the tracker.

The nominal trajectory, the plant, the tracking law and its log.
"""
