"""solarnav sim layer."""
