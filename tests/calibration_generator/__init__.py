"""Calibration data with hidden truth for ``cmm-comp calibrate`` (issue 27), see README.md."""
