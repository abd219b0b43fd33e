"""Coastal radars + AIS (multi-radar, two-radar identification papers): alignment, two-step
synchronisation, track-to-track association, fusion, AIS identification, scoring, SIAP,
cross-track deviation and radar registration bias."""
