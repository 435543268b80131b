"""Flight recordings in the EuRoC-MAV layout of ``recordings.md``: read, write, align."""
