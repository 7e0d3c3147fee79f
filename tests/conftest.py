"""Test-wide settings: no MLflow telemetry, deterministic CPU threads."""

import os

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
