"""borescan: laser displacement sensor bore scans to calibrated devices and certified diameters."""

__version__ = "0.1.0"
