"""Prefect flows composing the tasks (accelcal.tasks)."""
