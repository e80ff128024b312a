"""Snapshot uploads: parse and validate a body, store it all or nothing."""
