"""bench: ground-support test benches for spacecraft attitude sensors."""

__version__ = "0.1.0"
