"""Airfield surface surveillance (airfield paper): SMR + MLAT + VASN fusion with channel
integrity and reconfiguration. Configuration, frames (eq. 3–4), association, the fusion
stage, calibration and scoring; the filter kernels live in ``pipeline.filters``."""
