"""Engine types, aircraft, engines, installations, maintenance and fleet status."""
