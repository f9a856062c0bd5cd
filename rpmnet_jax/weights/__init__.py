"""Weights: official PyTorch names ⇄ our params, checkpoint loading, the shipped model (``*.npz`` + card)."""
