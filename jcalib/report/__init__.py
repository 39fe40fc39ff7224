"""Human-readable output of results: console tables (and, later, HTML reports)."""
