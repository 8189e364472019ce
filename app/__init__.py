"""solarnav app layer."""
