"""The one place that assembles a virtual world: a model drive, its faces on transports,
the real-time host, `hil drive`, the virtual bench and the model taps (ground truth)."""
