"""Operations: scheduled drops (serve), fleet SQL views (fleet),
calibration reports (report), task-runner selection for scale-out (runners).

Heavy imports (prefect, matplotlib) happen inside the functions that need them.
"""
