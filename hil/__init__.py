"""hil: hardware-in-the-loop test harness for servo drives."""

__version__ = "0.1.0"
