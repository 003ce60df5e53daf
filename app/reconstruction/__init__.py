"""app/reconstruction: preprocessing, seed interpolation, noise-aware and deviation models."""

from app.reconstruction.preprocess import CleanPoints, PreprocessParams, ReconstructionError, preprocess
from app.reconstruction.reconstruct import METHODS, Reconstruction, ReconstructParams, fit_deviation, reconstruct

__all__ = [
    "CleanPoints", "PreprocessParams", "ReconstructionError", "preprocess", "METHODS",
    "Reconstruction", "ReconstructParams", "fit_deviation", "reconstruct",
]
