"""The demo operator and its simulated fleet."""
