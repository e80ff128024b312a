"""Trends per engine serial number and per tail."""
