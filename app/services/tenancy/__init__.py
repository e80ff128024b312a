"""Operators and their API keys."""
