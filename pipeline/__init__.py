"""surveil: batch analytics for multi-sensor surveillance logs."""

__version__ = "0.1.0"
