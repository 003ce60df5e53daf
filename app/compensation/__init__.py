"""app/compensation."""
