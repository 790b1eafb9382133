"""Simulated datasets: Dataset 1 surrogate (chapter 3) and Dataset 2 (chapter 4)."""

from jaxcal.simulate.dataset1 import Dataset1, Dataset1Config, dataset1
from jaxcal.simulate.dataset2 import Dataset2, Dataset2Config, Samples, Sequences, dataset2
from jaxcal.simulate.drift import DriftConfig, DriftData, simulate_drift
from jaxcal.simulate.multipos import simulate_poses

__all__ = ["Dataset1", "Dataset1Config", "dataset1", "DriftConfig", "DriftData", "simulate_drift", "Dataset2", "Dataset2Config", "Samples", "Sequences", "dataset2", "simulate_poses"]
