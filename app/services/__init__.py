"""Business logic. Services take a session from the caller and never commit on their own."""
