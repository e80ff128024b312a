"""Pydantic request and response models (not tables: those are in app/models)."""
