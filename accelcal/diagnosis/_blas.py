"""Kept for the diagnosis' imports: the single-thread BLAS switch lives in accelcal.fitting.blas."""
from ..fitting.blas import single_thread  # noqa: F401
