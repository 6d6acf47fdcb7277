"""The stable-baselines3 side of fmu-bridge: training, evaluation and deployed agents.

This is the only package that imports torch and stable-baselines3.
"""
