"""File output helpers: atomic writes."""
