"""Wire protocols shared by faces, drivers and the recorder (pure: no I/O, no clock)."""
