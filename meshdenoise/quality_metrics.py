"""Alias of :mod:`meshdenoise.metrics` (normal error, distances and volume change live there now)."""

from __future__ import annotations

from .metrics import max_distance, mean_distance, normal_error_deg, point_surface_distances, volume_change

__all__ = ["normal_error_deg", "mean_distance", "max_distance", "volume_change", "point_surface_distances"]
