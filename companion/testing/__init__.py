"""Telemetry-driven scenario testing: a GCS-side recorder and the pytest plugin built on it."""
