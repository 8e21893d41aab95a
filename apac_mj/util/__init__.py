"""Helpers below every layer: the --set grammar (overrides), atomic file writes (files), where shipped data lives (paths)."""
