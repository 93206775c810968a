"""Reproductions of the published tables and figures (Yang 2017, Wang 2017)."""
