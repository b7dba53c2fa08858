"""accelcal."""
