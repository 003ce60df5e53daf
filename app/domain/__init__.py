"""What every core package shares: the domain's exception family and parameter checks.
Pure: imports only the standard library."""
