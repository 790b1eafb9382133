"""Simulated datasets: Dataset 1 surrogate (chapter 3) and Dataset 2 (chapter 4)."""

from jaxcal.simulate.dataset2 import Dataset2, Dataset2Config, Samples, Sequences, dataset2

__all__ = ["Dataset2", "Dataset2Config", "Samples", "Sequences", "dataset2"]
