"""faces."""

# reasons a face keeps of the frames, segments or levels it refused: the last few, so that a
# hostile flood does not grow a drive's memory
ERRORS_KEPT = 20
