"""Forecasts across data gaps (distributed maritime observation paper): a bootstrap
particle filter with admissible-area constraints."""
