"""solarnav calib layer."""
