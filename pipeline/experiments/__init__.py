"""Seeded Monte Carlo experiments: simulator + family stages, measured against truth."""
