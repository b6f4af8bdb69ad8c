"""Tests of the timing room (hil/timing)."""
