"""solarnav estimators layer."""
