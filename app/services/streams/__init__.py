"""Stream recordings and their estimation."""
