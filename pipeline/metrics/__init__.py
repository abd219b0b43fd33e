"""Evaluation metrics of the fused picture against truth."""
