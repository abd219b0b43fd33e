"""`surveil config init`: a site config from the recordings (survey, registration,
coastline, the commented TOML)."""
