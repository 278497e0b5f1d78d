"""The independent reference (VTK-based, float64) and the audits that use it: see README.md."""
