"""vnhc_gym: Gymnasium benchmark environments for virtual nonholonomic constraints."""

__version__ = "0.1.0"
