"""Recordings: our MCAP writer (ros2 profile), readers, the env and node recorders, export,
Rerun replay and Zenoh playback, with one recording clock.

May import the task, the experiment and the network's wire format; never the env.
"""

from bridge.recording.env_recorder import RecordMcap, default_run_name, record_env

__all__ = ["RecordMcap", "default_run_name", "record_env"]
