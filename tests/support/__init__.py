"""Validation harnesses: the product's pipeline scored against simulated truth."""
